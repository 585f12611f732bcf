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
from tools.sigkill_launcher import alive, children, cmdline

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
START_S = 120.0  # generous: a busy 2-core machine starts 5 interpreters slowly


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
    left = [p for p in children(proc.pid) if alive(p)]
    for p in [*left, proc.pid]:
        try:
            os.kill(p, signal.SIGKILL)
        except ProcessLookupError:
            pass
    proc.wait()
    return left


def _check_stopped(proc: subprocess.Popen, record: Path, lines: list[str], descendants: list[int], status_is: int | None = None,
                   within_s: float = 60.0) -> str:
    try:
        status = proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        _cleanup(proc)
        pytest.fail("the launcher did not exit within 60 s of the signal")
    deadline = time.monotonic() + within_s
    while any(alive(p) for p in descendants) and time.monotonic() < deadline:
        time.sleep(0.1)
    stdout = proc.stdout.read()
    left = [p for p in descendants if alive(p)]
    for p in left:
        os.kill(p, signal.SIGKILL)
    assert not left, f"processes left behind: {[cmdline(p) for p in left]}"
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
    return stdout


@pytest.mark.parametrize("how", ["ctrl-c to the process group", "SIGTERM to the coordinator", "SIGINT to the launcher",
                                 "SIGTERM to the launcher", "SIGHUP to the launcher"])
def test_stopping_leaves_a_finished_recording_and_no_process(tmp_path: Path, how: str) -> None:
    proc, record, lines = _launch_until_running(tmp_path)
    descendants = children(proc.pid)
    try:
        if how == "ctrl-c to the process group":
            os.killpg(proc.pid, signal.SIGINT)
        elif how == "SIGTERM to the coordinator":
            coordinator = [p for p in descendants if "inchworm.spawn - coordinator" in cmdline(p)]
            assert len(coordinator) == 1
            os.kill(coordinator[0], signal.SIGTERM)
        elif how == "SIGINT to the launcher":
            os.kill(proc.pid, signal.SIGINT)
        elif how == "SIGHUP to the launcher":  # the terminal closed: the same path as SIGTERM
            os.kill(proc.pid, signal.SIGHUP)
        else:
            os.kill(proc.pid, signal.SIGTERM)
        expected = {"SIGHUP to the launcher": 128 + signal.SIGHUP, "SIGTERM to the launcher": 128 + signal.SIGTERM}.get(how)
        said = _check_stopped(proc, record, lines, descendants, expected) + "".join(lines)
        # a user's stop is a clean stop: no robot declared lost by it, and what the launcher says of its run-wide stop is true
        assert " lost" not in said, said
        stopped = next(line for line in said.splitlines() if "emergency stop sent to run" in line)
        if how in ("ctrl-c to the process group", "SIGTERM to the coordinator"):  # the agents got the signal too / the run is over
            assert "acknowledged by 0 of" not in stopped, stopped
        if how != "ctrl-c to the process group":  # only the launcher was signalled: every agent was there to acknowledge
            assert "acknowledged by 4 of 4 agents" in stopped, stopped
    finally:
        if proc.poll() is None:
            _cleanup(proc)


@pytest.mark.parametrize("signum", [signal.SIGKILL, signal.SIGHUP])
def test_a_killed_gateway_launcher_leaves_no_process_no_folder_and_a_finished_recording(tmp_path: Path, signum: int) -> None:
    """SIGKILL of ``swarm launch --driver gateway``: nothing can run in the launcher, so its children (emulator, the port
    processes of links and agents, coordinator) notice it gone by themselves and exit within seconds; the guardian
    removes the temporary folder."""
    proc, record, lines = _launch_until_running(tmp_path, "--driver=gateway")
    descendants = children(proc.pid)
    assert any("inchworm.spawn - port" in cmdline(p) for p in descendants) and any("inchworm.spawn - emulator" in cmdline(p) for p in descendants)
    try:
        os.kill(proc.pid, signum)
        _check_stopped(proc, record, lines, descendants, 128 + signum if signum != signal.SIGKILL else -signal.SIGKILL, within_s=10.0)
    finally:
        if proc.poll() is None:
            _cleanup(proc)


def test_the_stop_counts_acknowledgements_and_agents_that_had_exited() -> None:
    """``stop_answers``: an agent process that exited before the stop (a Ctrl-C reached it too) is counted as exited, not as
    silent, and the wait ends as soon as every robot is one or the other."""
    import queue as queues

    from inchworm.launcher import stop_answers, stop_text
    from runtime.wire.keys import estop_ack_key
    from runtime.wire.messages import EstopAck, encode

    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    serving = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        inbox: queues.Queue = queues.Queue()
        for robot in (2, 3):  # robots 2 and 3 share the serving process; 0 and 1 the exited one
            inbox.put((estop_ack_key("r"), encode(EstopAck(run="r", step=0, stop_stamp_ns=7, by="agent", name=str(robot), robots=(robot,)))))
        inbox.put((estop_ack_key("r"), encode(EstopAck(run="r", step=0, stop_stamp_ns=6, by="agent", name="1", robots=(1,)))))  # an older stop
        start = time.monotonic()
        heard, exited = stop_answers(inbox, 7, time.monotonic() + 10.0, {0: gone, 1: gone, 2: serving, 3: serving})
        assert (heard, exited) == ({2, 3}, {0, 1}) and time.monotonic() - start < 5.0
        heard, exited = stop_answers(queues.Queue(), 8, time.monotonic() + 0.3, {0: gone, 2: serving})
        assert (heard, exited) == (set(), {0})  # robot 2 did not answer within the wait
    finally:
        serving.kill()
        serving.wait()
    assert stop_text("r", 2, 2, 4) == "emergency stop sent to run r (acknowledged by 2 of 4 agents; the other 2 had already exited)"
    assert stop_text("r", 0, 4, 4).endswith("its 4 agents had already exited (a stop signal reached them too)")
    assert stop_text("r", 1, 1, 4) == "emergency stop sent to run r (acknowledged by 1 of 4 agents; 1 had already exited)"
