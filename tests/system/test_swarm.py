"""``inchworm.Swarm``: a launched run as an object (start, status, emergency stop, result), real processes on loopback
(a run to its end with its status and JSON object: tests/system/test_examples.py::test_launched_run)."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest

import inchworm
from inchworm import FaultOptions, LaunchOptions, OutputOptions, SwarmOptions


def descendants(pid: int) -> list[int]:
    """Every descendant of ``pid`` (from /proc): the launcher and what it started (processes from specs name no run)."""
    try:
        kids = [int(kid) for kid in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []
    return kids + [grandchild for kid in kids for grandchild in descendants(kid)]


def alive(pids: list[int], within_s: float = 10.0) -> list[int]:
    """Those of ``pids`` still running (not zombies) after at most ``within_s`` (the launcher's folder guardian ends
    just after the launcher)."""
    def running(pid: int) -> bool:
        try:
            return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
        except OSError:
            return False

    deadline = time.monotonic() + within_s
    while (left := [pid for pid in pids if running(pid)]) and time.monotonic() < deadline:
        time.sleep(0.1)
    return left


def wait_for(run: inchworm.Swarm, ready, timeout_s: float = 90.0) -> inchworm.SwarmStatus:
    deadline = time.monotonic() + timeout_s
    while True:
        status = run.status()
        if ready(status):
            return status
        assert time.monotonic() < deadline and status.state != "ended", status
        time.sleep(0.2)


def test_estop_stops_the_run_and_leaving_the_block_leaves_no_process(tmp_path):
    options = LaunchOptions(swarm=SwarmOptions(robots=3, configs=30, motion_time=0.3, method="no-anchors"),
                            outputs=OutputOptions(no_record=True, out=tmp_path))
    before = set(descendants(os.getpid()))  # what earlier tests in this process left (a worker pool's resource tracker)
    with inchworm.Swarm(options) as run:
        wait_for(run, lambda s: len(s.agents) == 3 and s.coordinators)
        started = [pid for pid in descendants(os.getpid()) if pid not in before]
        assert len(started) >= 5  # the launcher, 3 agent processes, the coordinator
        stopped = run.estop("the test stops it")
        assert stopped.agents == [0, 1, 2] and stopped.run == run.run_id
        result = run.wait(timeout=120)
    assert result.status == 3  # a run that was stopped: a run error (docs/development.md)
    assert result.summary is None and result.to_json() == {}  # a stopped run prints no summary (docs/failure-model.md)
    assert alive(started) == []

    with inchworm.Swarm(options) as early:  # left while it runs: stopped as Ctrl-C stops swarm launch
        wait_for(early, lambda s: len(s.agents) == 3)
        started = [pid for pid in descendants(os.getpid()) if pid not in before]
        assert len(started) >= 4  # the launcher and 3 agent processes
    assert not early.running() and early.result().status == 128 + signal.SIGTERM
    assert alive(started) == []


def test_the_whole_anchor_search_reaches_the_coordinator(tmp_path):
    """The launcher's child gets every field of the options (its launch spec), the search's fields that no flag sets too:
    the coordinator records them."""
    from coordinator.selection.genetic import GeneticConfig
    from coordinator.selection.selector import SelectionConfig
    from runtime.recording.mcap_log import recording_info

    selection = SelectionConfig(final_samples=64, genetic=GeneticConfig(patience=5), mc_start="estimate")
    options = LaunchOptions(swarm=SwarmOptions(robots=3, configs=1, method="no-anchors", selection=selection),
                            outputs=OutputOptions(record=tmp_path / "run.mcap", out=tmp_path))
    with inchworm.Swarm(options) as run:
        assert run.wait(timeout=120).status == 0
    recorded = recording_info(tmp_path / "run.mcap")["metadata"]["run"]["selection"]
    assert (recorded["final_samples"], recorded["genetic"]["patience"], recorded["mc_start"]) == (64, 5, "estimate")


def test_a_run_that_cannot_start_raises_the_launchers_error(tmp_path):
    options = LaunchOptions(swarm=SwarmOptions(robots=3, min_robots=5), outputs=OutputOptions(no_record=True, out=tmp_path),
                            faults=FaultOptions())
    with pytest.raises(inchworm.OptionError, match="^min_robots must be between 2 and the 3 robots of the run, got 5$"):
        with inchworm.Swarm(options) as run:
            run.wait(timeout=60)
