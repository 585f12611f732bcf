"""The link judges the right party and lets the robots' watchdogs stop them when nobody can reach them any more.

Real processes (router, emulator on ptys, link) and real signals; loopback, free ports, every process stopped by pid.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from inchworm.processes import start_emulator, stop_all
from inchworm.specs import EmulatorSpec
from runtime.gateway.config import GatewayConfig, Port
from runtime.models.trajectory import random_trajectory
from runtime.wire.keys import coord_alive_key, link_alive_key
from runtime.wire.messages import LinkRequest, MotionCommand, encode, message_key
from runtime.wire.transport import ZenohSettings, alive_now, declare_token, open_session, publish
from tests.routers import start_router
from tests.waiting import wait_for

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}



def _events(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.exists() else []


def _site(tmp_path: Path, robots: int, procs: list[subprocess.Popen], motion_time: float = 0.0) -> tuple[list[int], Path, Path]:
    """An emulator of ``robots`` robots behind one port (``--events``); the robot ids, the live config and the event log."""
    traj = random_trajectory(robots, 1, np.random.default_rng(4))
    traj_file, config, live, events = tmp_path / "traj.json", tmp_path / "gw.json", tmp_path / "live.json", tmp_path / "events.jsonl"
    traj.save(traj_file)
    ids = [int(i) for i in traj.ids]
    GatewayConfig((Port("radio0", "emulated", tuple(ids)),)).save(config)
    start_emulator(EmulatorSpec(config=str(config), trajectory=str(traj_file), write_config=str(live), events=str(events), motion_time=motion_time),
                   procs, env=ENV)
    return ids, live, events


def _link(live: Path, run: str, hub: str, procs: list[subprocess.Popen]) -> subprocess.Popen:
    link = subprocess.Popen([sys.executable, "-m", "swarm_cli.link", f"--config={live}", "--port=radio0", f"--run={run}",
                             f"--hub={hub}"], env=ENV, stderr=subprocess.PIPE, text=True)
    procs.append(link)
    return link


def _command(session, run: str, robot: int, epoch: int) -> None:
    """Command step 1 (0.1 m) of ``robot`` as coordinator ``epoch`` does, and forward it to the link as its agent does."""
    cmd = MotionCommand(run=run, step=1, robot=robot, config=1, turn_rad=0.0, drive_m=0.1, epoch=epoch)
    request = LinkRequest(run=run, step=1, robot=robot, kind="command", turn_rad=0.0, drive_m=0.1, epoch=epoch)
    for msg in (cmd, request):
        publish(session, message_key(msg), encode(msg))


def test_a_link_resuming_from_its_own_stall_heartbeats_before_it_judges_its_robots(tmp_path):
    procs: list[subprocess.Popen] = []
    try:
        ids, live, events = _site(tmp_path, 5, procs)
        hub = start_router(procs, ENV)
        link = _link(live, "stall", hub, procs)
        with open_session(ZenohSettings("client", connect=(hub,))) as session:
            wait_for(lambda: alive_now(session, link_alive_key("stall", "radio0")), 30, "the link")
            time.sleep(0.5)  # heartbeats answered
            link.send_signal(signal.SIGSTOP)  # the link stalls 2.7 s, longer than robot_timeout_s (2 s); the robots are fine
            time.sleep(2.7)
            link.send_signal(signal.SIGCONT)
            time.sleep(1.5)
        link.terminate()
        _, err = link.communicate(timeout=15)
        assert "was stalled for" in err, err
        assert "silent" not in err and "ERROR" not in err, err
    finally:
        stop_all(procs)


def test_when_the_router_dies_the_link_stops_feeding_and_the_robot_watchdog_stops_a_motion(tmp_path):
    """A robot in the middle of a 4 s motion: the router is SIGKILLed, so no stop can be sent any more. The link
    loses the coordinator with its session and stops heartbeating and retransmitting; the robot's watchdog
    (heartbeat_timeout_s) aborts the motion within about a second."""
    procs: list[subprocess.Popen] = []
    try:
        ids, live, events = _site(tmp_path, 2, procs, motion_time=4.0)
        hub = start_router(procs, ENV)
        router = procs[-1]
        link = _link(live, "dead", hub, procs)
        session = open_session(ZenohSettings("client", connect=(hub,)))
        try:
            wait_for(lambda: alive_now(session, link_alive_key("dead", "radio0")), 30, "the link")
            token = declare_token(session, coord_alive_key("dead", 1))  # a coordinator appears: the link begins a run
            wait_for(lambda: len([e for e in _events(events) if e["event"] == "run"]) == len(ids), 10, "RUN at every robot")
            _command(session, "dead", ids[0], 1)
            wait_for(lambda: [e for e in _events(events) if e["event"] == "accepted"], 10, "the robot moving")
            router.kill()
            router.wait()
            killed_ns = time.time_ns()
            aborted = wait_for(lambda: [e for e in _events(events) if e["event"] == "aborted"], 5, "the watchdog's stop")
            assert "watchdog" in aborted[0]["reason"]
            print(f"motion aborted by the robot's watchdog {(aborted[0]['time_ns'] - killed_ns) / 1e6:.0f} ms after the router died")
            assert aborted[0]["time_ns"] - killed_ns < 2.5e9
            assert not [e for e in _events(events) if e["event"] == "executed"]  # the 4 s motion never completed
            del token
        finally:
            session.close()
        link.terminate()
        _, err = link.communicate(timeout=15)
        assert "the coordinator is gone" in err, err
    finally:
        stop_all(procs)


def test_a_coordinator_takeover_keeps_the_robots_fed_and_the_accepted_motion_completes(tmp_path):
    """A robot in the middle of a 3 s motion: the coordinator's token (epoch 1) disappears and its successor's (epoch 2,
    parent 1) appears 0.3 s later, as a standby taking the run over. The link feeds the robots again without a new
    RUN: the motion is not aborted and completes. A coordinator of a new run (parent 0) while epoch 2 lives is ignored."""
    procs: list[subprocess.Popen] = []
    try:
        ids, live, events = _site(tmp_path, 2, procs, motion_time=3.0)
        hub = start_router(procs, ENV)
        link = _link(live, "takeover", hub, procs)
        with open_session(ZenohSettings("client", connect=(hub,))) as session:
            wait_for(lambda: alive_now(session, link_alive_key("takeover", "radio0")), 30, "the link")
            first = declare_token(session, coord_alive_key("takeover", 1))
            wait_for(lambda: len([e for e in _events(events) if e["event"] == "run"]) == len(ids), 10, "RUN at every robot")
            _command(session, "takeover", ids[0], 1)
            wait_for(lambda: [e for e in _events(events) if e["event"] == "accepted"], 10, "the robot moving")
            first.undeclare()
            time.sleep(0.3)
            second = declare_token(session, coord_alive_key("takeover", 2, 1))
            other = declare_token(session, coord_alive_key("takeover", 5))  # a second master: refused by the agents
            wait_for(lambda: [e for e in _events(events) if e["event"] == "executed"], 10, "the motion done")
            assert not [e for e in _events(events) if e["event"] == "aborted"]
            assert len([e for e in _events(events) if e["event"] == "run"]) == len(ids)  # the same run: no new RUN
            other.undeclare()
            second.undeclare()
        link.terminate()
        _, err = link.communicate(timeout=15)
        assert "epoch 2 took the run over from epoch 1" in err and "epoch 5 appeared while epoch 2 runs; ignored" in err, err
    finally:
        stop_all(procs)
