"""swarm replay (--publish, --check) and swarm plot on the recording of a real distributed run (swarm launch).

The run: 4 agent processes + coordinator on a loopback hub, ``inchworm-equal-speed`` (seeded
genetic anchor search, 2 steps per configuration), 2 configurations; recorded into tmp_path.
"""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import threading
import uuid
from pathlib import Path

import pytest

from runtime.recording.mcap_log import read_messages, recording_info
from runtime.wire.transport import open_loopback_hub, open_session, subscribe
from swarm_cli.main import main

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}


def swarm(*args: str, timeout: float = 120, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "swarm_cli.main", *map(str, args)], capture_output=True, text=True,
                          cwd=REPO, env=ENV, timeout=timeout, **kwargs)


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("replay")
    path = tmp / "run.mcap"
    proc = swarm("launch", "-n", "4", "--configs", "2", "--method", "inchworm-equal-speed", "--seed", "3",
                 "--run", f"r{uuid.uuid4().hex[:8]}", "--record", path, "--out", tmp / "plots", timeout=180)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert f"recorded {path}: " in proc.stdout, proc.stdout + proc.stderr
    return path


def _run_messages(path: Path) -> list[tuple[str, bytes]]:
    return [(k, p) for k, p, _t, _pub in read_messages(path) if k.startswith("swarm/")]


def test_check_reproduces_the_recorded_run(recording, capsys):
    assert main(["replay", str(recording), "--check", "--json"]) == 0
    out = capsys.readouterr().out
    result = json.loads(out.strip().splitlines()[-1])
    # initial estimate + 2 configurations x 2 steps + 1 step of an approach leg (configuration 2: robots 1 and 2 drive
    # 0.41 and 0.28 m into places 9.6 cm apart, where their straight drives' ends touch with probability 4e-3, so both
    # stop at a staging point and drive on together); 2 plans from the seeded anchor search and the leg's
    assert "check passed: 6 estimates, 3 plans reproduced" in out
    assert result["passed"] and result["estimates"] == 6 and result["plans"] == 3 and result["skipped"] == []
    assert result["exact"] is True  # recorded on this machine: compared bit for bit
    assert "not bit for bit" not in out


def test_check_reports_the_first_divergence(recording, capsys):
    assert main(["replay", str(recording), "--check", "--bearing-sigma-deg", "3", "--what-if", "--json"]) == 1
    out = capsys.readouterr().out
    d = json.loads(out.strip().splitlines()[-1])["divergence"]
    assert "check FAILED" in out and "divergence at step" in out
    assert d["step"] >= 1 and d["recorded"] != d["recomputed"] and d["field"]


def test_check_on_an_unfinished_recording(recording, tmp_path, capsys):
    data = recording.read_bytes()
    footer = len(data) - 8 - 29  # footer record (opcode, length, summary_start, summary_offset_start, crc), then the magic
    summary_start = struct.unpack("<Q", data[footer + 9: footer + 17])[0]
    assert 0 < summary_start < footer
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:summary_start])  # as if the recorder was killed just before finishing the file
    assert not recording_info(cut)["complete"]
    assert main(["replay", str(cut), "--check"]) == 0
    assert "check passed: 6 estimates, 3 plans reproduced" in capsys.readouterr().out


def test_plot_from_recording(recording, tmp_path, capsys):
    out = tmp_path / "plots"
    assert main(["plot", str(recording), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "2 of 2 configurations, 5 steps, P_f = " in text  # one of them an approach leg's (above)
    for name in ("trajectory.png", "errors.png"):
        assert (out / name).stat().st_size > 1000 and str(out / name) in text


def _collect(session, got: list, done: threading.Event, total: int) -> None:
    def on_sample(key: str, payload: bytes) -> None:
        got.append((key, payload))
        if len(got) >= total:
            done.set()
    subscribe(session, "swarm/**", on_sample)


def test_publish_own_hub_as_fast_as_possible(recording):
    expected = _run_messages(recording)
    proc = subprocess.Popen([sys.executable, "-m", "swarm_cli.main", "replay", str(recording), "--publish", "--speed", "0", "--same-run"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO, env=ENV)
    try:
        line = proc.stdout.readline()  # where it publishes, first, on stdout
        assert " on tcp/127.0.0.1:" in line and "a hub this command opened on loopback" in line, line
        hub = line.split(" on ", 1)[1].split(" ")[0]
        got: list[tuple[str, bytes]] = []
        done = threading.Event()
        from runtime.wire.transport import ZenohSettings
        with open_session(ZenohSettings("client", connect=(hub,))) as session:
            _collect(session, got, done, len(expected))
            out, err = proc.communicate(timeout=60)
            done.wait(5)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert f"replayed {len(expected)} messages" in out
    assert got == expected  # every message, same keys, same bytes, same order


def test_publish_on_a_hub_with_timing(recording):
    expected = _run_messages(recording)
    times = [t for k, _p, t, _pub in read_messages(recording) if k.startswith("swarm/")]
    span = (times[-1] - times[0]) / 1e9
    hub_session, _, hub = open_loopback_hub()
    got: list[tuple[str, bytes]] = []
    done = threading.Event()
    with hub_session as session:
        _collect(session, got, done, len(expected))
        proc = swarm("replay", recording, "--publish", "--speed", "4", "--hub", hub, "--json", "--same-run")
        done.wait(5)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got == expected
    assert result["elapsed_s"] >= 0.95 * span / 4  # recorded timing, 4x faster
    assert result["elapsed_s"] < span / 4 + 2.0


def test_corrupt_and_truncated_files_exit_2_without_traceback(recording, tmp_path):
    noise = tmp_path / "noise.mcap"
    noise.write_bytes(os.urandom(3000))
    header = tmp_path / "header.mcap"
    header.write_bytes(recording.read_bytes()[:14])
    damaged = tmp_path / "damaged.mcap"
    data = bytearray(recording.read_bytes())
    pos = 8
    while data[pos] != 0x06:  # the first chunk record
        pos += 9 + struct.unpack("<Q", data[pos + 1: pos + 9])[0]
    length = struct.unpack("<Q", data[pos + 1: pos + 9])[0]
    middle = pos + 9 + length // 2
    data[middle: middle + 64] = bytes(64)  # garbage inside the compressed records
    damaged.write_bytes(bytes(data))
    cases = [(noise, ("replay", "--publish", "--wait", "0"), "not an MCAP file"), (noise, ("plot",), "not an MCAP file"),
             (header, ("replay", "--check"), "truncated header"), (damaged, ("plot",), "corrupt"),
             (damaged, ("replay", "--publish", "--wait", "0"), "corrupt")]
    for path, command, words in cases:
        args = [command[0], path, *command[1:]] + (["--out", tmp_path / "p"] if command[0] == "plot" else [])
        proc = swarm(*args)
        assert proc.returncode == 2, (command, proc.stdout, proc.stderr)
        assert "Traceback" not in proc.stderr and str(path) in proc.stderr and words in proc.stderr, (command, proc.stderr)
        assert "replayed" not in proc.stdout
    assert not (tmp_path / "p").exists()
