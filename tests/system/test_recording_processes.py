"""MCAP recording with real processes: a SIGKILLed recorder loses at most the last flush interval; `swarm info` and
`swarm recover` on good and broken files as subprocesses."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader

from runtime.recording.mcap_log import read_messages, recording_info, recover
from tests.integration.test_recording import _complete_file

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
RUN = "rec1"


CHILD = """
import sys, time
from runtime.wire.messages import Status, encode, message_key
from runtime.recording.mcap_log import McapRecorder
rec = McapRecorder(sys.argv[1], "killed", {"seed": 1})
i = 0
while True:
    m = Status(run="killed", step=i, robot=i % 3, state="accepted", reason="")
    t = time.time_ns()
    rec.write(message_key(m), encode(m), log_time_ns=t)
    print(i, t, flush=True)
    i += 1
    time.sleep(0.002)
"""


def test_sigkill_loses_at_most_the_last_flush_interval(tmp_path):
    path = tmp_path / "killed.mcap"
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(path)], stdout=subprocess.PIPE, text=True, cwd=REPO, env=ENV)
    reported: list[tuple[int, int]] = []
    try:
        assert child.stdout is not None
        while len(reported) < 400:  # about 1 s of messages at ~400/s (2 ms sleep + work)
            line = child.stdout.readline()
            assert line, "recorder child exited early"
            i, t = map(int, line.split())
            reported.append((i, t))
    finally:
        os.kill(child.pid, signal.SIGKILL)
        rest, _ = child.communicate(timeout=10)
    reported += [tuple(map(int, line.split())) for line in rest.splitlines() if line.strip()]
    assert child.returncode == -signal.SIGKILL

    with open(path, "rb") as f:
        with pytest.raises(McapError):  # the seeking reader needs the summary the killed recorder never wrote
            list(make_reader(f).iter_messages())
    got = list(read_messages(path))
    assert got, "no complete chunk survived"
    times = [t for _k, _p, t, _pub in got]
    # an exact prefix of what the child wrote, in order, bytes intact
    assert times == [t for _i, t in reported[: len(got)]]
    lost_s = (reported[-1][1] - times[-1]) / 1e9
    lost_n = len(reported) - len(got)
    print(f"SIGKILL: {len(reported)} written, {len(got)} readable, lost {lost_n} messages = last {lost_s * 1e3:.0f} ms")
    assert lost_s <= 0.5, f"lost the last {lost_s:.3f} s ({lost_n} messages)"

    info = recording_info(path)
    assert not info["complete"] and info["reader"] == "stream" and info["messages"] == len(got)
    assert info["metadata"]["run"]["seed"] == 1 and "recorder" not in info["metadata"]
    assert info["undecodable"] == 0

    out = tmp_path / "killed.recovered.mcap"
    result = recover(path, out)
    assert result["messages"] == len(got) and not result["source_complete"]
    with open(out, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        assert reader.get_summary() is not None
        again = [(ch.topic, msg.data, msg.log_time, msg.publish_time) for _s, ch, msg in reader.iter_messages(log_time_order=False)]
        assert [m.name for m in reader.iter_metadata()] == ["run"]
    assert again == got
    assert recording_info(out)["complete"]


def test_cli_info_recover_and_errors(tmp_path, capsys):
    from swarm_cli.main import main

    good = _complete_file(tmp_path)
    killed = tmp_path / "cut.mcap"
    data = good.read_bytes()
    killed.write_bytes(data[: len(data) * 2 // 3])
    assert main(["info", str(killed), "--json"]) == 0
    info = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert info["complete"] is False and 0 < info["messages"] < 1500
    assert main(["recover", str(killed)]) == 0
    assert "wrote" in capsys.readouterr().out
    recovered = tmp_path / "cut.recovered.mcap"
    assert recording_info(recovered)["messages"] == info["messages"]

    noise = tmp_path / "noise.mcap"
    noise.write_bytes(os.urandom(3000))
    proc = subprocess.run([sys.executable, "-m", "swarm_cli.main", "info", str(noise)], capture_output=True, text=True, cwd=REPO, env=ENV, timeout=60)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and "not an MCAP file" in proc.stderr and str(noise) in proc.stderr


