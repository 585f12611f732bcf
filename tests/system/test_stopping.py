"""Every way of stopping a launched run leaves a finished, indexed recording and no process behind.

Real processes and real signals: ``swarm launch`` is started in its own process group,
interrupted once the coordinator reports its agents alive, and the recording is then read
with the seeking reader (which needs the summary and indexes of a finished file).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from mcap.reader import SeekingReader

from runtime.recording.mcap_log import counts_text, recording_info

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
START_S = 120.0  # generous: a busy 2-core machine starts 5 interpreters slowly


def _children(pid: int) -> list[int]:
    """Every descendant of ``pid`` (from /proc), deepest last."""
    out: list[int] = []
    try:
        kids = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return out
    for kid in map(int, kids):
        out.append(kid)
        out += _children(kid)
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _launch_until_running(tmp_path: Path, *extra: str) -> tuple[subprocess.Popen, Path, list[str]]:
    """``swarm launch`` (4 robots, slow motion) in its own session, returned once its coordinator runs the trajectory;
    its temporary folders go to ``tmp_path / "tmp"``."""
    record = tmp_path / "run.mcap"
    (tmp_path / "tmp").mkdir()
    cmd = [sys.executable, "-m", "swarm_cli.main", "launch", "-n", "4", "--configs", "4", "--motion-time", "0.5",
           "--run", f"stop{os.getpid()}", f"--record={record}", f"--out={tmp_path / 'out'}", *extra]
    proc = subprocess.Popen(cmd, cwd=tmp_path, env={**ENV, "TMPDIR": str(tmp_path / "tmp")}, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    lines: list[str] = []
    running = threading.Event()

    def read() -> None:
        for line in proc.stderr:
            lines.append(line)
            if "agents alive" in line:
                running.set()
        running.set()

    threading.Thread(target=read, daemon=True).start()
    if not running.wait(START_S) or proc.poll() is not None:
        _cleanup(proc)
        pytest.fail(f"the run did not start: {''.join(lines)}")
    return proc, record, lines


def _cleanup(proc: subprocess.Popen) -> list[int]:
    """Kill (by pid) whatever of the run is still alive; the pids that were."""
    left = [p for p in _children(proc.pid) if _alive(p)]
    for p in [*left, proc.pid]:
        try:
            os.kill(p, signal.SIGKILL)
        except ProcessLookupError:
            pass
    proc.wait()
    return left


def _check_stopped(proc: subprocess.Popen, record: Path, lines: list[str], descendants: list[int], status_is: int | None = None,
                   within_s: float = 60.0) -> None:
    try:
        status = proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        _cleanup(proc)
        pytest.fail("the launcher did not exit within 60 s of the signal")
    deadline = time.monotonic() + within_s
    while any(_alive(p) for p in descendants) and time.monotonic() < deadline:
        time.sleep(0.1)
    stdout = proc.stdout.read()
    left = [p for p in descendants if _alive(p)]
    for p in left:
        os.kill(p, signal.SIGKILL)
    assert not left, f"processes left behind: {[_cmdline(p) for p in left]}"
    assert status != 0, "an interrupted run must not report success"
    if status_is is not None:
        assert status == status_is, "".join(lines)
    tmp = record.parent / "tmp"
    deadline = time.monotonic() + 5.0
    while list(tmp.glob("swarm-launch-*")) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not list(tmp.glob("swarm-launch-*")), "the launcher's temporary folder was left behind"
    info = recording_info(record)
    assert info["complete"] and info["indexed"] and info["reader"] == "seeking", (info["problem"], "".join(lines))
    assert info["messages"] > 0
    assert f"recorded {record}: {counts_text(info)}" in stdout  # the coordinator's count is swarm info's
    with open(record, "rb") as f:  # the seeking reader itself: summary, chunk indexes, CRCs
        reader = SeekingReader(f, validate_crcs=True)
        assert reader.get_summary().statistics.message_count == info["messages"]
        assert sum(1 for _ in reader.iter_messages()) == info["messages"]
    assert "recorder" in info["metadata"] and info["metadata"]["recorder"]["clean_stop"] is True


@pytest.mark.parametrize("how", ["ctrl-c to the process group", "SIGTERM to the coordinator", "SIGINT to the launcher",
                                 "SIGTERM to the launcher", "SIGHUP to the launcher"])
def test_stopping_leaves_a_finished_recording_and_no_process(tmp_path: Path, how: str) -> None:
    proc, record, lines = _launch_until_running(tmp_path)
    descendants = _children(proc.pid)
    try:
        if how == "ctrl-c to the process group":
            os.killpg(proc.pid, signal.SIGINT)
        elif how == "SIGTERM to the coordinator":
            coordinator = [p for p in descendants if "inchworm.spawn - coordinator" in _cmdline(p)]
            assert len(coordinator) == 1
            os.kill(coordinator[0], signal.SIGTERM)
        elif how == "SIGINT to the launcher":
            os.kill(proc.pid, signal.SIGINT)
        elif how == "SIGHUP to the launcher":  # the terminal closed: the same path as SIGTERM
            os.kill(proc.pid, signal.SIGHUP)
        else:
            os.kill(proc.pid, signal.SIGTERM)
        expected = {"SIGHUP to the launcher": 128 + signal.SIGHUP, "SIGTERM to the launcher": 128 + signal.SIGTERM}.get(how)
        _check_stopped(proc, record, lines, descendants, expected)
    finally:
        if proc.poll() is None:
            _cleanup(proc)


@pytest.mark.parametrize("signum", [signal.SIGKILL, signal.SIGHUP])
def test_a_killed_gateway_launcher_leaves_no_process_no_folder_and_a_finished_recording(tmp_path: Path, signum: int) -> None:
    """SIGKILL of ``swarm launch --driver gateway``: nothing can run in the launcher, so its children (emulator, the port
    processes of links and agents, coordinator) notice it gone by themselves and exit within seconds; the guardian
    removes the temporary folder."""
    proc, record, lines = _launch_until_running(tmp_path, "--driver=gateway")
    descendants = _children(proc.pid)
    assert any("inchworm.spawn - port" in _cmdline(p) for p in descendants) and any("inchworm.spawn - emulator" in _cmdline(p) for p in descendants)
    try:
        os.kill(proc.pid, signum)
        _check_stopped(proc, record, lines, descendants, 128 + signum if signum != signal.SIGKILL else -signal.SIGKILL, within_s=10.0)
    finally:
        if proc.poll() is None:
            _cleanup(proc)
