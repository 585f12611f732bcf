"""The Foxglove live view beside a real `swarm launch`: served while the run goes, and after it until Ctrl-C."""

from __future__ import annotations

import base64
import os
import re
import socket
import sys

import pytest

from runtime.recording.mcap_log import recording_info


def test_demo_serves_the_live_view_while_it_runs(tmp_path):
    import subprocess

    pytest.importorskip("foxglove")

    out = subprocess.run([sys.executable, "-m", "swarm_cli.main", "launch", "-n", "3", "--configs", "1", "--method", "no-anchors",
                          "--no-record", "--foxglove", "0", "--linger", "0", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert re.search(r"live view for the Foxglove app at ws://127\.0\.0\.1:[1-9]\d*\n", out.stderr), out.stderr  # port 0: a free one


def test_the_live_view_keeps_serving_after_the_run_until_ctrl_c(tmp_path):
    """The run ends, its recording is finished, and the view still accepts a WebSocket client until SIGINT."""
    import signal
    import subprocess

    pytest.importorskip("foxglove")

    record = tmp_path / "run.mcap"
    launch = subprocess.Popen([sys.executable, "-m", "swarm_cli.main", "launch", "-n", "3", "--configs", "1", "--method", "no-anchors",
                               f"--record={record}", "--foxglove", "0", "--out", str(tmp_path)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        lines = []
        for line in launch.stderr:
            lines.append(line)
            if "keeps serving" in line:
                break
        assert "until Ctrl-C" in lines[-1], "".join(lines)
        port = int(re.search(r"live view for the Foxglove app at ws://127\.0\.0\.1:(\d+)", "".join(lines))[1])  # the one it got
        assert recording_info(record)["indexed"]  # the run and its recording are finished while the view serves
        with socket.create_connection(("127.0.0.1", port), timeout=5) as conn:
            key = base64.b64encode(os.urandom(16)).decode()
            conn.sendall((f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                          f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                          "Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n").encode())
            assert conn.recv(4096).decode(errors="replace").startswith("HTTP/1.1 101")
        os.killpg(launch.pid, signal.SIGINT)
        launch.wait(timeout=60)
        assert "P_f = " in launch.stdout.read()
    finally:
        if launch.poll() is None:
            launch.kill()
            launch.wait()


