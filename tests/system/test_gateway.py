"""The hardware path without hardware: link process, gateway driver and agents against robot emulators on ptys.

In-process rigs (real Zenoh on loopback, a real pty, the link engine on its own thread)
check the link's reliability; subprocess runs check the whole path as users run it.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import msgpack
import numpy as np
import pytest

from inchworm.processes import default_gateway, start_agents, start_emulator, start_gateway, stop_all
from inchworm.specs import AgentHostSpec, EmulatorSpec
from robot_agent.driver import DriverRefused, RobotLost, SimDriver
from robot_agent.emulator import EmulatedWorld, FaultPlan, PortEmulator
from robot_agent.gateway_driver import GatewayDriver
from robot_agent.link import Link, SerialLink
from runtime.gateway.config import Calibration, GatewayConfig, Limits, Port, Timing
from runtime.models.config import ModelConfig
from runtime.models.trajectory import random_trajectory
from runtime.recording.mcap_log import read_messages
from runtime.wire.keys import alive_wildcard, coord_alive_key, link_alive_key
from runtime.wire.messages import (
    RUN_STOPPED_REFUSAL,
    EmergencyStop,
    LinkReply,
    LinkRequest,
    LinkStats,
    MotionCommand,
    ObserveRequest,
    Status,
    decode,
    encode,
    message_key,
)
from runtime.wire.transport import (
    ZenohSettings,
    alive_now,
    declare_token,
    open_loopback_hub,
    open_session,
    publish,
    subscribe,
    subscribe_queue,
)
from swarm_cli.agent import main as agent_main
from tests.waiting import wait_for

REPO = Path(__file__).resolve().parents[2]
PY = [sys.executable, "-m"]
CFG = ModelConfig()
POSES = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 1.0]])
FAST = Timing(ack_timeout_s=0.05, max_retries=3, motion_timeout_s=2.0, heartbeat_period_s=5.0, heartbeat_timeout_s=10.0,
              robot_timeout_s=20.0, stats_period_s=0.2)


@dataclasses.dataclass
class Rig:
    emulator: PortEmulator
    link: Link
    driver: GatewayDriver
    member: object
    thread: threading.Thread  # the link engine's
    coordinator: object  # the session acting as the live coordinator of ``EPOCH`` ...
    token: object  # ... and its liveliness token (None once undeclared)

    def order(self, cmd: MotionCommand) -> None:
        """Publish ``cmd`` as the coordinator does, on the robot's own key."""
        publish(self.coordinator, message_key(cmd), encode(cmd))

    def execute(self, cmd: MotionCommand) -> None:
        """The coordinator commands ``cmd`` and the agent's driver executes it."""
        self.order(cmd)
        self.driver.execute(cmd)

    def sense(self, step: int):
        """The coordinator asks robot 0 for its observations of ``step`` and the agent's driver senses them."""
        ask = ObserveRequest(run="gw", step=step, robot=0, epoch=EPOCH)
        publish(self.coordinator, message_key(ask), encode(ask))
        return self.driver.sense(None, step)


@contextmanager
def rig(faults: FaultPlan = FaultPlan(), timing: Timing = FAST, calibration: Calibration = Calibration(),
        port_robots: tuple[int, ...] = (0,), run: str = "gw", limits: Limits = Limits(), motion_time_s: float = 0.0,
        local: bool = False) -> Iterator[Rig]:
    """Robot 0 of a world of robots 0 and 1 (seed 3) behind an emulated port with ``port_robots``, a link
    engine (with ``limits``) and robot 0's gateway driver correcting ``calibration``, which is also robot 0's
    true deviation; motions take ``motion_time_s``. ``local``: the driver and the link share a session and talk
    directly (``GatewayDriver.use_link``, as in a port process), else over Zenoh from another session."""
    world = EmulatedWorld([0, 1], POSES, CFG, seed=3, heartbeat_timeout_s=timing.heartbeat_timeout_s,
                          calibration={0: calibration}, motion_time_s=motion_time_s)
    hub, member, _ = open_loopback_hub()
    with PortEmulator(world, "radio0", port_robots, faults) as emulator, hub, \
            open_session(member) as link_session, open_session(member) as agent_session, open_session(member) as coord_session:
        device = SerialLink(emulator.device, 115200)
        link = Link(link_session, run, Port("radio0", emulator.device, port_robots), timing, device, limits, {0: calibration})
        driver = GatewayDriver(run, 0, calibration, timing, port="radio0")
        if local:
            driver.use_link(link)
        thread = threading.Thread(target=link.run, daemon=True)
        thread.start()
        driver.attach(link_session if local else agent_session)
        try:
            deadline = time.monotonic() + 5
            while not link.counters.rtts_ms and faults.drop_prob < 1:  # the first heartbeat was answered: the path is up
                assert time.monotonic() < deadline, "no heartbeat answer from the emulator"
                time.sleep(0.005)
            assert driver.ready(5), "the link's liveliness token (declared after its subscriptions) never came"
            token = declare_token(coord_session, coord_alive_key(run, EPOCH))  # a live coordinator: the link begins a run
            wait_for(lambda: link.counters.epoch != 0 and all(rb.begin is None for rb in link.robots.values()), 5,
                     "the run begun at every robot (RUN_ACK)")
            r = Rig(emulator, link, driver, member, thread, coord_session, token)
            yield r
            if r.token is not None:
                r.token.undeclare()
        finally:
            driver.detach()
            link.stop()
            thread.join(timeout=5)
            device.close()


EPOCH = 3  # tests that command agents directly act as the coordinator of this epoch


def act_as_coordinator(session, run_id: str):
    """Declare the token of the coordinator of ``EPOCH`` for ``run_id`` (agents obey only a live coordinator); keep it."""
    token = declare_token(session, coord_alive_key(run_id, EPOCH))
    time.sleep(0.3)  # the agents and links learn of it
    return token


def command(step: int, turn: float = 0.3, drive: float = 0.1, start_pose=()) -> MotionCommand:
    return MotionCommand(run="gw", step=step, robot=0, config=1, turn_rad=turn, drive_m=drive, start_pose=start_pose, epoch=EPOCH)


def simulated_pose(turns_drives: list[tuple[float, float]], scale: float = 1.0) -> np.ndarray:
    """Robot 0's pose after these commands in the simulated driver, with float32 values as on the wire."""
    sim = SimDriver(0, [0, 1], POSES[0], CFG, seed=3)
    for step, (turn, drive) in enumerate(turns_drives, 1):
        sim.execute(MotionCommand(run="gw", step=step, robot=0, config=1, turn_rad=float(np.float32(turn)),
                                  drive_m=float(np.float32(drive / scale)) * scale))
    return sim.true_pose()


# rx/tx frame 0 is the first heartbeat and its answer, 1 the coordinator's RUN and its RUN_ACK; tx 2, 3 are ACCEPTED and
# DONE of the first command (rx 2)
@pytest.mark.parametrize("faults,what", [
    (FaultPlan(drop_tx=frozenset({2, 3})), "both answers lost"),
    (FaultPlan(drop_rx=frozenset({2})), "the command frame lost"),
])
@pytest.mark.parametrize("local", [False, True], ids=["over Zenoh", "in one process"])
def test_a_lost_frame_costs_one_retransmission_and_one_execution(faults, what, local):
    with rig(faults, local=local) as r:
        r.execute(command(1))
        assert r.link.counters.retransmissions == 1, what
        assert r.emulator.executed(0) == 1, what
        r.execute(command(2, -0.2, 0.05))  # the next command goes through untouched
        assert r.link.counters.retransmissions == 1 and r.emulator.executed(0) == 2
        np.testing.assert_allclose(r.emulator.world.pose(0), simulated_pose([(0.3, 0.1), (-0.2, 0.05)]), atol=1e-12)


@pytest.mark.parametrize("local", [False, True], ids=["over Zenoh", "in one process"])
def test_observations_and_calibration_through_the_link(local):
    cal = Calibration(range_bias_m=0.02, bearing_offset_rad=0.1, motion_scale=0.9)
    with rig(calibration=cal, port_robots=(0, 1), local=local) as r:
        r.execute(command(1, 0.0, 0.1))
        observed, ranges, bearings = r.sense(1)
    # the same robot simulated without miscalibration: the corrections undo the emulated deviations
    sim = SimDriver(0, [0, 1], POSES[0], CFG, seed=3)
    sim.execute(MotionCommand(run="gw", step=1, robot=0, config=1, turn_rad=0.0, drive_m=float(np.float32(0.1 / 0.9)) * 0.9))
    exp_ids, exp_r, exp_b = sim.sense({0: sim.true_pose(), 1: POSES[1]}, 1)
    assert observed.tolist() == exp_ids.tolist() == [1]
    np.testing.assert_allclose(ranges, exp_r, atol=1e-6)
    np.testing.assert_allclose(bearings, exp_b, atol=1e-6)


def test_a_robot_served_in_the_links_process_is_recorded_the_same_and_takes_no_requests_from_the_wire():
    """A driver talking to its link directly (``use_link``) still publishes its requests and gets the link's replies
    published, so a recorder sees the same messages; a request someone else publishes for that robot is not served."""
    with rig(local=True) as r, open_session(r.member) as other:
        seen: list[tuple[str, bytes]] = []
        _subs = [subscribe(other, f"swarm/gw/robot/0/{k}", lambda key, payload: seen.append((key, payload))) for k in ("linkreq", "linkrep")]
        for key in ("swarm/gw/robot/0/linkreq", "swarm/gw/robot/0/linkrep"):  # the link's session knows the subscriber
            probe = r.link.session.declare_publisher(key)
            wait_for(lambda probe=probe: probe.matching_status.matching, 10, f"a subscriber of {key} known to the link's session")
            probe.undeclare()
        r.execute(command(1))
        wait_for(lambda: any(k.endswith("linkrep") for k, _ in seen), 5, "the link's reply, published")
        assert decode(next(p for k, p in seen if k.endswith("linkreq")), LinkRequest).kind == "command"
        assert decode(next(p for k, p in seen if k.endswith("linkrep")), LinkReply).kind == "done"
        publish(other, "swarm/gw/robot/0/linkreq", encode(_request(step=2)))  # well-formed, but not from the robot's agent
        time.sleep(0.5)
        assert r.emulator.executed(0) == 1 and r.link.stats().rejected == 0


def test_a_silent_robot_is_reported_lost_by_id():
    with rig() as r:
        r.emulator.faults = FaultPlan(drop_prob=1.0)
        start = time.monotonic()
        with pytest.raises(RobotLost, match=r"robot 0 did not answer the command of step 1 after 3 retransmissions"):
            r.execute(command(1))
        assert time.monotonic() - start < 2.0
        assert r.link.stats().lost == (0,) and r.link.counters.timeouts == 1 and r.emulator.executed(0) == 0


def test_corrupted_answers_are_rejected_and_recovered():
    with rig(FaultPlan(corrupt_prob=0.3, seed=1)) as r:
        for step in range(1, 9):
            r.execute(command(step, 0.05, 0.02))
        stats = r.link.stats()
        assert r.emulator.executed(0) == 8
        assert stats.crc_errors > 0 and stats.retransmissions > 0
        assert r.emulator.stats().tx_corrupted >= stats.crc_errors


def _request(**fields) -> LinkRequest:  # a request as anyone allowed on ``linkreq`` may publish it
    return LinkRequest(**({"run": "gw", "step": 1, "robot": 0, "kind": "command", "turn_rad": 0.1, "drive_m": 0.1} | fields))


def test_hostile_link_requests_are_dropped_counted_and_never_sent():
    """Schema-valid requests the frame cannot carry or the limits forbid, undecodable ones, foreign ones: the link
    drops and counts each (before any byte reaches the robot) and serves on."""
    limits = Limits(max_drive_m=0.5, workspace=(-0.5, -0.5, 0.5, 0.5))
    with rig(limits=limits) as r, open_session(r.member) as session:
        r.execute(command(1, 0.1, 0.05, POSES[0]))  # the robot is at step 1
        valid = msgpack.unpackb(encode(_request(step=2, start_pose=[0.0, 0.0, 0.0])))
        hostile = [
            encode(_request(step=2**32 + 5)),  # crashed the link before: beyond the frame's u32 step
            encode(_request(step=2, turn_rad=1e39)),  # beyond float32
            encode(_request(step=2, drive_m=1e39)),
            encode(_request(step=2, drive_m=2.0)),  # 2 m past the 0.5 m limit
            encode(_request(step=2, turn_rad=4.0)),  # beyond max_turn_rad (pi)
            encode(_request(step=2, drive_m=0.2, start_pose=[0.45, 0.0, 0.0])),  # would leave the workspace
            encode(_request(step=2, drive_m=0.2)),  # no start pose: the workspace cannot be checked
            encode(_request(step=5000)),  # far in the future: would strand the robot's step memory
            encode(_request(run="other", step=2)),  # another run's, on this run's key
            msgpack.packb(valid | {"turn_rad": float("nan")}),
            msgpack.packb(valid | {"drive_m": float("inf")}),
            msgpack.packb(valid | {"step": -1}),
            msgpack.packb(valid | {"kind": "selfdestruct"}),
            b"\x00\xffnot msgpack",
        ]
        for payload in hostile:
            publish(session, "swarm/gw/robot/0/linkreq", payload)
        wait_for(lambda: r.link.stats().rejected == len(hostile), 10, "every hostile request counted")
        assert r.thread.is_alive() and r.emulator.executed(0) == 1  # none of them moved the robot
        r.execute(command(2, 0.1, 0.05, simulated_pose([(0.1, 0.05)])))  # the link still serves
        assert r.emulator.executed(0) == 2 and r.link.stats().rejected == len(hostile)
        np.testing.assert_allclose(r.emulator.world.pose(0), simulated_pose([(0.1, 0.05), (0.1, 0.05)]), atol=1e-12)


def _answer_or_drop(r: Rig, replies: list[LinkReply], step: int, send: Callable[[], None]) -> str:
    """``send()`` a request of ``step``, then what the link made of it: ``"answered"`` or ``"dropped"``."""
    rejected = r.link.stats().rejected
    send()
    wait_for(lambda: any(rep.step == step for rep in replies) or r.link.stats().rejected > rejected, 5,
             f"the link's answer to the request of step {step}, or its drop")
    return "answered" if any(rep.step == step for rep in replies) else "dropped"


def test_the_link_checks_the_coordinators_own_commands_against_its_reckoning_of_the_workspace():
    """The coordinator commands ten 0.5 m moves toward x < -1 with a start pose that never moves (a stale estimate):
    the link's own reckoning (moved by every DONE) stops them at the workspace's edge; a command beyond the limits is
    dropped even though the coordinator sent it."""
    limits = Limits(max_drive_m=0.5, workspace=(-1.2, -1.0, 1.0, 1.0))
    with rig(limits=limits) as r, open_session(r.member) as agent:
        replies: list[LinkReply] = []
        sub = subscribe(agent, "swarm/gw/robot/0/linkrep", lambda key, payload: replies.append(decode(payload, LinkReply)))
        outcomes = []
        for step in range(1, 11):
            cmd = command(step, math.pi if step == 1 else 0.0, 0.5, [0.0, 0.0, 0.0])
            request = _request(step=step, turn_rad=cmd.turn_rad, drive_m=0.5, start_pose=[0.0, 0.0, 0.0], epoch=EPOCH)
            outcomes.append(_answer_or_drop(r, replies, step, lambda cmd=cmd, request=request: (
                r.order(cmd), publish(agent, "swarm/gw/robot/0/linkreq", encode(request)))))
        assert outcomes == ["answered"] * 2 + ["dropped"] * 8  # 0 -> -0.5 -> -1.0; the third would end at -1.5
        assert r.emulator.executed(0) == 2 and r.emulator.world.pose(0)[0] >= -1.2
        beyond = command(11, 0.0, 0.8, [-1.0, 0.0, math.pi])  # beyond max_drive_m: a coordinator with other limits
        request = _request(step=11, turn_rad=0.0, drive_m=0.8, epoch=EPOCH)
        assert _answer_or_drop(r, replies, 11, lambda: (r.order(beyond), publish(agent, "swarm/gw/robot/0/linkreq", encode(request)))) == "dropped"
        sub.undeclare()
        assert r.emulator.executed(0) == 2 and r.link.counters.unauthorised == 0  # commanded, but beyond the limits


FORGERIES = {  # what a client with the gateway identity (allowed to publish linkreq) sends, and why it must not move
    "a made-up start pose": lambda: _request(step=2, turn_rad=0.0, drive_m=0.5, start_pose=[0.0, 0.0, 0.0], epoch=EPOCH),
    "the next step with another motion": lambda: _request(step=2, turn_rad=0.0, drive_m=0.5, epoch=EPOCH),
    "a future step": lambda: _request(step=101, turn_rad=0.0, drive_m=0.5, epoch=EPOCH),
    "a stale step": lambda: _request(step=1, turn_rad=0.0, drive_m=0.5, epoch=EPOCH),
    "another epoch": lambda: _request(step=2, turn_rad=0.3, drive_m=0.1, epoch=EPOCH + 1),
    "no coordinator alive": lambda: _request(step=2, turn_rad=0.3, drive_m=0.1, epoch=EPOCH),
    "an observation of a future step": lambda: _request(step=50, kind="observe", turn_rad=0.0, drive_m=0.0),
}


@pytest.mark.parametrize("forgery", list(FORGERIES))
def test_forged_link_requests_never_move_a_robot(forgery):
    """Through the gateway identity (a client allowed on ``linkreq``), against a real link and an emulated robot: the
    robot executed step 1; the coordinator commands step 2 (turn 0.3, drive 0.1) unless it is gone. The forgery is
    dropped and counted as unauthorised, the robot does not move, and its step memory is not taken over: the
    coordinator's observation of step 1 and its step 2 then go through as asked."""
    with rig() as r, open_session(r.member) as forger:
        r.execute(command(1, 0.1, 0.05))
        pose = r.emulator.world.pose(0).copy()
        if forgery == "no coordinator alive":
            r.token.undeclare()  # the coordinator is gone (the run ended, or it died)
            r.token = None
            wait_for(lambda: r.link._coord_gone, 5, "the link sees no coordinator alive")
        elif forgery != "a made-up start pose":
            r.order(command(2))
        unauthorised = r.link.counters.unauthorised
        publish(forger, "swarm/gw/robot/0/linkreq", encode(FORGERIES[forgery]()))
        wait_for(lambda: r.link.counters.unauthorised > unauthorised, 5, "the forgery dropped and counted")
        time.sleep(0.1)
        assert r.emulator.executed(0) == 1
        np.testing.assert_array_equal(r.emulator.world.pose(0), pose)
        if forgery != "no coordinator alive":
            r.sense(1)  # the coordinator's observation of step 1
            r.execute(command(2))  # the coordinator's step 2 executes as commanded
            assert r.emulator.executed(0) == 2
            np.testing.assert_allclose(r.emulator.world.pose(0), simulated_pose([(0.1, 0.05), (0.3, 0.1)]), atol=1e-12)


def test_the_coordinators_own_command_forwarded_again_moves_nothing():
    """A copy of the coordinator's command of the step just executed (a re-send, or a replay by the gateway
    identity) is sent to the robot, which answers DONE from memory without moving."""
    with rig() as r, open_session(r.member) as forger:
        r.execute(command(1, 0.1, 0.05))
        replies: list[LinkReply] = []
        sub = subscribe(forger, "swarm/gw/robot/0/linkrep", lambda key, payload: replies.append(decode(payload, LinkReply)))
        copy = _request(step=1, turn_rad=0.1, drive_m=0.05, epoch=EPOCH)
        assert _answer_or_drop(r, replies, 1, lambda: publish(forger, "swarm/gw/robot/0/linkreq", encode(copy))) == "answered"
        sub.undeclare()
        assert replies[-1].kind == "done" and r.emulator.executed(0) == 1


@pytest.mark.parametrize("watchdog_s,survives", [(Timing().heartbeat_timeout_s, True), (1.0, False)],
                         ids=["default watchdog", "a watchdog shorter than the retry budget"])
def test_a_radio_blackout_of_a_second_during_a_motion_is_survived(watchdog_s, survives):
    """The radio goes dead for 1.2 s right after the robot accepted a 1.5 s motion (the link retransmits, hears
    nothing, then the DONE). The default watchdog (2 s) outlasts the retry budget (1.6 s) plus one retransmission,
    so the motion completes; the former 1 s watchdog stopped the robot mid-motion."""
    timing = dataclasses.replace(Timing(), heartbeat_timeout_s=watchdog_s)
    with rig(FaultPlan(blackout=(1, 1.2)), timing=timing, motion_time_s=1.5) as r:
        if survives:
            r.execute(command(1))
            assert r.emulator.executed(0) == 1 and r.link.stats().lost == ()
            assert r.emulator.stats().rx_dropped > 0  # the blackout did happen
        else:
            with pytest.raises(DriverRefused, match="stopped by the watchdog"):
                r.execute(command(1))
            assert r.emulator.executed(0) == 0


def test_a_forged_lost_reply_for_another_step_is_ignored_and_counted():
    with rig(motion_time_s=0.5) as r, open_session(r.member) as session:
        failed: list[BaseException] = []
        worker = threading.Thread(target=lambda: _catch(lambda: r.execute(command(1)), failed))
        worker.start()
        wait_for(lambda: r.emulator.stats().tx_frames >= 2, 5, "ACCEPTED")  # the driver waits for step 1
        forged = LinkReply(run="gw", step=99, robot=0, kind="lost", reason="forged", observed=[], ranges=[], bearings=[])
        publish(session, message_key(forged), encode(forged))
        worker.join(timeout=10)
        assert not failed and r.driver.ignored_replies == 1 and r.emulator.executed(0) == 1


def test_a_lost_done_after_a_long_motion_costs_one_retry_interval():
    """The link re-sends the COMMAND every ack_timeout_s while the robot moves; the robot answers ACCEPTED,
    then DONE from memory, so losing the DONE (and whatever else in 0.5 s around it) delays the step by
    about one interval, not a motion timeout, and the robot moves once. The retry budget (2 s) leaves a loaded
    machine's late wake-up room before the silence would count as a lost robot."""
    timing = dataclasses.replace(FAST, ack_timeout_s=0.05, max_retries=39, motion_timeout_s=5.0)
    with rig(timing=timing, motion_time_s=0.5) as r:
        failed: list[BaseException] = []
        start = time.monotonic()
        worker = threading.Thread(target=lambda: _catch(lambda: r.execute(command(1)), failed))
        worker.start()
        wait_for(lambda: r.emulator.executed(0) == 0 and r.emulator.stats().tx_frames >= 2, 5, "ACCEPTED")
        accepted = time.monotonic()
        time.sleep(max(0.0, accepted + 0.3 - time.monotonic()))
        r.emulator.faults = FaultPlan(drop_prob=1.0)  # the radio is dead around the end of the motion: DONE lost
        time.sleep(0.5)  # within the retry budget, 40 x 0.05 s
        r.emulator.faults = FaultPlan()
        worker.join(timeout=10)
        took = time.monotonic() - start
        assert not failed and r.emulator.executed(0) == 1
        assert r.emulator.stats().tx_dropped >= 1 and r.link.counters.retransmissions >= 8  # re-sent during the motion
        assert took < 3.0  # about one retry interval after the radio came back (~0.9 s), not the 5 s motion timeout


def test_a_robot_dying_mid_motion_is_lost_within_the_retry_budget():
    timing = dataclasses.replace(FAST, ack_timeout_s=0.05, max_retries=3, motion_timeout_s=30.0)
    with rig(timing=timing, motion_time_s=20.0) as r:
        failed: list[BaseException] = []
        worker = threading.Thread(target=lambda: _catch(lambda: r.execute(command(1)), failed))
        worker.start()
        wait_for(lambda: r.emulator.stats().tx_frames >= 2, 5, "ACCEPTED")
        start = time.monotonic()
        r.emulator.faults = FaultPlan(drop_prob=1.0)  # the radio goes dead while the robot moves
        worker.join(timeout=10)
        assert failed and isinstance(failed[0], RobotLost) and "did not answer the command of step 1" in str(failed[0])
        assert time.monotonic() - start < timing.retry_budget_s + 4.0  # the retry budget (0.2 s), not the 30 s motion timeout


def _catch(fn, into: list) -> None:
    try:
        fn()
    except BaseException as exc:  # noqa: BLE001 - handed to the test thread
        into.append(exc)


def test_an_idle_driver_notices_its_link_disappear():
    with rig() as r:
        reasons: list[str] = []
        r.driver.on_lost = reasons.append
        r.driver.check()  # link alive: nothing
        r.link.stop()
        r.thread.join(timeout=5)
        wait_for(lambda: reasons, 5, "the lost callback")
        assert reasons == ["robot 0: the link process of port radio0 is gone"]
        with pytest.raises(RobotLost, match="the link process of port radio0 is gone"):
            r.driver.check()


# -- whole processes ----------------------------------------------------------------------------


def _launch(tmp: Path, driver: str, traj_file: Path, run_id: str, record: Path | None) -> dict:
    result = tmp / f"{driver}.json"
    cmd = [sys.executable, "-m", "swarm_cli.main", "launch", f"--trajectory={traj_file}", f"--driver={driver}", "--seed=2",
           f"--run={run_id}", f"--result={result}", f"--out={tmp / driver}", "--json"]
    cmd += [f"--record={record}"] if record else ["--no-record"]
    scratch = tmp / f"tmp-{driver}"
    scratch.mkdir()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=180, cwd=tmp, env={**os.environ, "TMPDIR": str(scratch)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "ERROR" not in proc.stderr and "Traceback" not in proc.stderr, proc.stderr[-3000:]  # agents stopped before links
    assert not list(scratch.glob("swarm-launch-*"))  # no temporary folder left (the run-file folder is the launcher's by design)
    return json.loads(result.read_text())


def test_gateway_run_equals_the_simulated_run_and_is_recorded(tmp_path):
    traj = random_trajectory(4, 2, np.random.default_rng(5))
    traj_file = tmp_path / "traj.json"
    traj.save(traj_file)
    recording = tmp_path / "gateway.mcap"
    sim = _launch(tmp_path, "sim", traj_file, "eq-sim", None)
    gw = _launch(tmp_path, "gateway", traj_file, "eq-gw", recording)
    assert len(gw["steps"]) == len(sim["steps"]) > 0
    for a, b in zip(gw["steps"], sim["steps"], strict=True):
        assert a["moving"] == b["moving"]  # the same plans
        # float32 on the wire (docs/gateway-protocol.md): equal to ~1e-7 m, not bit for bit
        np.testing.assert_allclose(a["commands"], b["commands"], atol=1e-6)
        np.testing.assert_allclose(a["poses"], b["poses"], atol=1e-6)
        np.testing.assert_allclose(a["truth"], b["truth"], atol=1e-6)
    keys = {}
    for key, payload, *_ in read_messages(recording):
        keys.setdefault(key, []).append(payload)
    stats = [decode(p, LinkStats) for p in keys["swarm/eq-gw/link/radio0/stats"]]
    assert stats[-1].frames_received > 0 and stats[-1].lost == ()
    replies = [decode(p, LinkReply) for k, v in keys.items() if k.endswith("/linkrep") for p in v]
    assert {r.kind for r in replies} == {"done", "observation"}
    # the port processes hand requests and replies to their link directly, and still publish them for the record
    requests = [decode(p, LinkRequest) for k, v in keys.items() if k.endswith("/linkreq") for p in v]
    assert {r.kind for r in requests} == {"command", "observe"}
    assert sum(r.kind == "done" for r in replies) == sum(r.kind == "command" for r in requests) == sum(sum(s["moving"]) for s in gw["steps"])



def _wait_routed(hub: str, keys: list[str], timeout_s: float = 10.0) -> None:
    """Until the hub routes each of ``keys`` to a subscriber (a probe publisher's matching status), so that
    what the agents publish from now on reaches the test's subscription."""
    with open_session(ZenohSettings("client", connect=(hub,))) as probe:
        for key in keys:
            publisher = probe.declare_publisher(key)
            wait_for(lambda publisher=publisher: publisher.matching_status.matching, timeout_s, f"a subscriber of {key} known to the hub")
            publisher.undeclare()


@dataclasses.dataclass
class Site:
    """A loopback hub, emulated robots on ptys and the gateway processes a test starts (all stopped by pid at the end)."""

    session: object
    hub: str
    ids: list[int]
    live: Path  # the gateway config with the emulator's pty devices
    procs: list[subprocess.Popen]

    def link(self, run: str, port: str = "radio0") -> subprocess.Popen:
        proc = subprocess.Popen(PY + ["swarm_cli.link", f"--config={self.live}", f"--port={port}", f"--run={run}", f"--hub={self.hub}"])
        self.procs.append(proc)
        return proc

    def agent(self, robot: int | str, run: str, *extra: str, **popen: object) -> subprocess.Popen:
        proc = subprocess.Popen(PY + ["swarm_cli.agent", f"--id={robot}", f"--ids={','.join(map(str, self.ids))}", f"--run={run}",
                                      f"--hub={self.hub}", "--driver=gateway", f"--gateway-config={self.live}", *extra], **popen)
        self.procs.append(proc)
        return proc


@contextmanager
def emulated_site(tmp_path: Path, robots: int, seed: int, config, **emulator) -> Iterator[Site]:
    """``robots`` emulated robots of a random trajectory, behind the ports ``config(ids)`` gives (``emulator``: more fields
    of its ``EmulatorSpec``); a hub and a session."""
    traj = random_trajectory(robots, 1, np.random.default_rng(seed))
    traj_file, config_file, live = tmp_path / "traj.json", tmp_path / "gw.json", tmp_path / "live.json"
    traj.save(traj_file)
    ids = [int(i) for i in traj.ids]
    config(ids).save(config_file)
    hub_session, member, hub = open_loopback_hub()
    procs: list[subprocess.Popen] = []
    try:
        with hub_session, open_session(member) as session:
            start_emulator(EmulatorSpec(config=str(config_file), trajectory=str(traj_file), write_config=str(live), **emulator), procs)
            yield Site(session, hub, ids, live, procs)
    finally:
        stop_all(procs, grace_s=5.0)
    assert all(p.returncode is not None for p in procs)


def test_estop_reaches_every_robot_within_100_ms_and_limits_refuse_before_any_byte(tmp_path):
    events = tmp_path / "events.jsonl"
    run_id = "estop"

    def config(ids):
        return GatewayConfig((Port("radio0", "emulated", tuple(ids[:2])), Port("radio1", "emulated", tuple(ids[2:]))),
                             limits=Limits(max_drive_m=0.3, workspace=(-5.0, -5.0, 5.0, 5.0)))

    with emulated_site(tmp_path, 4, 1, config, events=str(events)) as site:
        session, ids = site.session, site.ids
        site.link(run_id, "radio0")
        site.link(run_id, "radio1")
        for robot in ids:
            site.agent(robot, run_id)
        wait_for(lambda: len(alive_now(session, alive_wildcard(run_id))) == len(ids), 30, "every agent alive")
        _sub, statuses = subscribe_queue(session, f"swarm/{run_id}/robot/*/status")
        _wait_routed(site.hub, [f"swarm/{run_id}/robot/{r}/status" for r in ids])

        def status_of(robot: int, step: int) -> Status:
            def find():
                while not statuses.empty():
                    st = decode(statuses.get()[1], Status)
                    found[(st.robot, st.step)] = st
                return found.get((robot, step))
            return wait_for(find, 10, f"the status of robot {robot} at step {step}")

        found: dict = {}
        token = act_as_coordinator(session, run_id)
        # limits: a drive beyond max_drive_m is refused by the agent, no COMMAND frame reaches the robot
        too_far = MotionCommand(run=run_id, step=1, robot=ids[0], config=1, turn_rad=0.0, drive_m=0.5, epoch=EPOCH)
        publish(session, message_key(too_far), encode(too_far))
        assert status_of(ids[0], 1).state == "refused" and "exceeds the limit 0.3 m" in status_of(ids[0], 1).reason
        # workspace: the move would leave [-5, 5]^2 from the coordinator's estimate of the robot
        outside = MotionCommand(run=run_id, step=1, robot=ids[2], config=1, turn_rad=0.0, drive_m=0.2, start_pose=[4.9, 0.0, 0.0],
                                epoch=EPOCH)
        publish(session, message_key(outside), encode(outside))
        assert status_of(ids[2], 1).state == "refused" and "outside the workspace" in status_of(ids[2], 1).reason
        # emergency stop
        t0 = time.time_ns()
        stop = EmergencyStop(run=run_id, step=0, source="test", reason="test")
        publish(session, message_key(stop), encode(stop))

        def estops():
            if not events.exists():
                return None
            rows = [json.loads(line) for line in events.read_text().splitlines() if line.strip()]
            first = {}
            for row in rows:
                if row.get("event") == "estop":
                    first.setdefault(row["robot"], row["time_ns"])
            return first if set(first) == set(ids) else None

        first = wait_for(estops, 5, "ESTOP at every emulated robot")
        delays_ms = {robot: (t - t0) / 1e6 for robot, t in first.items()}
        print(f"estop delays ms: {delays_ms}")
        assert max(delays_ms.values()) < 100, delays_ms
        rows = [json.loads(line) for line in events.read_text().splitlines() if line.strip()]
        assert not [r for r in rows if r.get("event") in ("accepted", "executed")], "a command reached a robot"
        # after the stop every agent refuses commands
        cmd = MotionCommand(run=run_id, step=2, robot=ids[1], config=1, turn_rad=0.0, drive_m=0.1, epoch=EPOCH)
        publish(session, message_key(cmd), encode(cmd))
        refusal = status_of(ids[1], 2)
        assert (refusal.state, refusal.reason) == ("refused", f"{RUN_STOPPED_REFUSAL} by test (test)")
        token.undeclare()


def test_swarm_estop_counts_the_agents_and_links_that_acknowledged_and_fails_when_none_did(tmp_path):
    run_id = "acks"

    def config(ids):
        return GatewayConfig((Port("radio0", "emulated", tuple(ids[:2])), Port("radio1", "emulated", tuple(ids[2:]))))

    with emulated_site(tmp_path, 3, 2, config) as site:
        site.link(run_id, "radio0")
        site.link(run_id, "radio1")
        for robot in site.ids:
            site.agent(robot, run_id)
        wait_for(lambda: len(alive_now(site.session, alive_wildcard(run_id))) == len(site.ids), 30, "every agent alive")
        estop = [sys.executable, "-m", "swarm_cli.main", "estop", f"--hub={site.hub}", "--json"]
        done = subprocess.run([*estop, f"--run={run_id}"], capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stderr
        out = json.loads(done.stdout.splitlines()[-1])
        assert out["published"] == 3 and out["agents"] == sorted(site.ids) and out["links"] == ["radio0", "radio1"]
        assert out["robots"] == sorted(site.ids)
        assert f"acknowledged by 3 agents (robots {', '.join(map(str, sorted(site.ids)))}) and 2 links (ports radio0, radio1)" in done.stderr
        wrong = subprocess.run([*estop, "--run=acks-typo", "--ack-timeout=0.5"], capture_output=True, text=True, timeout=60)
        assert wrong.returncode == 1, wrong.stderr
        assert "no agent or link acknowledged it within 0.5 s" in wrong.stderr
        assert json.loads(wrong.stdout.splitlines()[-1]) == {"run": "acks-typo", "published": 3, "agents": [], "links": [], "robots": []}


def test_ctrl_c_of_the_launcher_stops_every_robot(tmp_path):
    events = tmp_path / "events.jsonl"
    launcher = subprocess.Popen([sys.executable, "-m", "swarm_cli.main", "launch", "--driver=gateway", "-n", "4", "--configs=4",
                                 "--motion-time=0.3", f"--emulator-events={events}", "--no-record", f"--out={tmp_path}"],
                                cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        def moving():
            return events.exists() and '"event":"accepted"' in events.read_text()
        wait_for(moving, 60, "a robot moving")
        launcher.send_signal(signal.SIGINT)
        _, err = launcher.communicate(timeout=30)
    finally:
        if launcher.poll() is None:
            launcher.kill()
            launcher.wait()
    assert "emergency stop sent" in err, err[-2000:]
    rows = [json.loads(line) for line in events.read_text().splitlines() if line.strip()]
    assert {r["robot"] for r in rows if r["event"] == "estop"} == {0, 1, 2, 3}
    assert "Traceback" not in err


def test_an_agent_whose_link_never_answers_drops_its_token_and_exits_3(tmp_path):
    config = tmp_path / "gw.json"
    GatewayConfig((Port("radio0", "/dev/null", (0,)),), timing=Timing(ack_timeout_s=0.05, max_retries=1, motion_timeout_s=0.5)).save(config)
    hub_session, member, hub = open_loopback_hub()
    with hub_session, open_session(member) as session:
        agent = subprocess.Popen([sys.executable, "-m", "swarm_cli.agent", "--id=0", "--ids=0", "--run=nolink",
                                  f"--hub={hub}", "--driver=gateway", f"--gateway-config={config}",
                                  "--ready-timeout=0.5"], stderr=subprocess.PIPE, text=True)
        try:
            wait_for(lambda: alive_now(session, alive_wildcard("nolink")), 20, "the agent's token")
            _sub, statuses = subscribe_queue(session, "swarm/nolink/robot/0/status")
            _wait_routed(hub, ["swarm/nolink/robot/0/status"])
            _token = act_as_coordinator(session, "nolink")
            cmd = MotionCommand(run="nolink", step=1, robot=0, config=1, turn_rad=0.0, drive_m=0.1, epoch=EPOCH)
            publish(session, message_key(cmd), encode(cmd))
            assert agent.wait(timeout=20) == 3
            assert alive_now(session, alive_wildcard("nolink")) == set()
            states = [decode(statuses.get(timeout=2)[1], Status) for _ in range(2)]
            assert [s.state for s in states] == ["accepted", "refused"] and states[1].reason.startswith("robot lost: robot 0")
        finally:
            if agent.poll() is None:
                agent.kill()
            _, err = agent.communicate(timeout=10)
    assert "robot 0 lost: robot 0: no answer from the link" in err and "Traceback" not in err


def test_bench_gateway_json_contract(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "swarm_cli.main", "bench", "gateway", "--robots=2", "--steps=3", "--rounds=1",
                           "--frames=2000", "--commands=5", "--json"], capture_output=True, text=True, timeout=180, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert set(result) == {"codec_frames_per_s", "pty_roundtrip_ms_median", "step_ms_median_gateway", "step_ms_median_sim"}
    assert all(isinstance(v, (int, float)) and v > 0 for v in result.values())
    assert "Traceback" not in proc.stderr


def test_a_killed_link_process_makes_its_agents_report_the_robot_lost_at_once(tmp_path):
    def config(ids):
        return GatewayConfig((Port("radio0", "emulated", tuple(ids)),), timing=Timing(motion_timeout_s=30.0))

    # motions of 20 s: the command is still running when the link dies
    with emulated_site(tmp_path, 2, 3, config, motion_time=20.0) as site:
        robot = site.ids[0]
        link = site.link("deadlink")
        agent = site.agent(robot, "deadlink", stderr=subprocess.PIPE, text=True)
        wait_for(lambda: alive_now(site.session, "swarm/deadlink/alive/**") >= {f"swarm/deadlink/alive/robot/{robot}",
                                                                                 "swarm/deadlink/alive/link/radio0"}, 30, "agent and link")
        _sub, statuses = subscribe_queue(site.session, f"swarm/deadlink/robot/{robot}/status")
        _wait_routed(site.hub, [f"swarm/deadlink/robot/{robot}/status"])
        _token = act_as_coordinator(site.session, "deadlink")
        cmd = MotionCommand(run="deadlink", step=1, robot=robot, config=1, turn_rad=0.0, drive_m=0.1, epoch=EPOCH)
        publish(site.session, message_key(cmd), encode(cmd))
        assert decode(statuses.get(timeout=10)[1], Status).state == "accepted"
        time.sleep(0.3)
        link.kill()  # SIGKILL: no goodbye from the link
        killed = time.monotonic()
        assert agent.wait(timeout=10) == 3
        assert time.monotonic() - killed < 3.0  # not the 30 s motion timeout
        refusal = decode(statuses.get(timeout=2)[1], Status)
        assert refusal.state == "refused" and "the link process of port radio0 is gone" in refusal.reason


def test_an_agent_declares_itself_alive_only_once_its_link_is_up(tmp_path):
    def config(ids):
        return GatewayConfig((Port("radio0", "emulated", tuple(ids)),))

    with emulated_site(tmp_path, 2, 4, config) as site:
        robot = site.ids[0]
        site.agent(robot, "late")
        time.sleep(2.0)  # long enough for an agent to start; its link is not there yet
        assert alive_now(site.session, alive_wildcard("late")) == set()
        site.link("late")
        wait_for(lambda: alive_now(site.session, alive_wildcard("late")), 20, "the agent's token once the link is up")
        _sub, statuses = subscribe_queue(site.session, f"swarm/late/robot/{robot}/status")
        _wait_routed(site.hub, [f"swarm/late/robot/{robot}/status"])
        _token = act_as_coordinator(site.session, "late")
        cmd = MotionCommand(run="late", step=1, robot=robot, config=1, turn_rad=0.1, drive_m=0.05, epoch=EPOCH)
        publish(site.session, message_key(cmd), encode(cmd))
        states = [decode(statuses.get(timeout=10)[1], Status).state for _ in range(2)]
        assert states == ["accepted", "done"]


def test_two_runs_back_to_back_on_the_same_emulator_and_links(tmp_path):
    """The robots, link processes and agents stay up; the second coordinator's appearance begins a new run (the
    agents forget their steps, the links send RUN with a new epoch), so its step 1 is not refused as stale
    and every robot executes each step once."""
    traj = random_trajectory(4, 2, np.random.default_rng(7))
    traj_file, events = tmp_path / "traj.json", tmp_path / "events.jsonl"
    traj.save(traj_file)
    hub_session, member, hub = open_loopback_hub()
    run_id = "twice"
    gateway = default_gateway(traj)
    procs: list[subprocess.Popen] = []
    try:
        with hub_session, open_session(member) as session:
            emulator = EmulatorSpec(config="", trajectory=str(traj_file), seed=2, events=str(events), hub=hub, run_id=run_id)
            live = start_gateway(gateway, tmp_path, emulator, procs)
            ids = {f"swarm/{run_id}/alive/link/{p.name}" for p in gateway.ports}
            wait_for(lambda: alive_now(session, f"swarm/{run_id}/alive/link/*") == ids, 30, "the link processes")
            agents = start_agents(traj, AgentHostSpec(run_id=run_id, robots=(), hub=hub, seed=2, driver="gateway", gateway_config=str(live)))
            procs += agents
            stable = list(procs)
            results = []
            for k in (1, 2):
                result = tmp_path / f"run{k}.json"
                coordinator = subprocess.run(
                    PY + ["swarm_cli.coordinator_cmd", f"--trajectory={traj_file}", f"--run={run_id}", f"--hub={hub}", "--seed=2",
                          f"--out={tmp_path / str(k)}", f"--result={result}", "--no-record", "--json"],
                    capture_output=True, text=True, timeout=180, cwd=tmp_path)
                assert coordinator.returncode == 0, coordinator.stderr[-3000:]
                results.append(json.loads(result.read_text()))
                assert all(p.poll() is None for p in stable), "the emulator, links and agents served both runs"
    finally:
        stop_all(procs[2:])
        stop_all(procs[:1])
    rows = [json.loads(line) for line in events.read_text().splitlines() if line.strip()]
    runs = [r for r in rows if r["event"] == "run"]
    assert len({r["epoch"] for r in runs}) == 2 and len(runs) == 2 * traj.n  # every robot began both runs
    assert not [r for r in rows if r["event"] == "refused"], [r for r in rows if r["event"] == "refused"][:3]
    executed = [(r["robot"], r["step"]) for r in rows if r["event"] == "executed"]
    assert executed and all(len(results[i]["steps"]) > 0 for i in (0, 1))
    second = runs[traj.n]["time_ns"]  # the steps of the second run start again at 1, each executed once per run
    first_run = [(r["robot"], r["step"]) for r in rows if r["event"] == "executed" and r["time_ns"] < second]
    second_run = [(r["robot"], r["step"]) for r in rows if r["event"] == "executed" and r["time_ns"] > second]
    assert len(set(first_run)) == len(first_run) and len(set(second_run)) == len(second_run) and min(s for _, s in second_run) == 1


@pytest.mark.parametrize("drop,corrupt,delay", [(0.1, 0.1, 0.05)])
def test_radio_faults_through_swarm_launch_leave_the_results_unchanged(drop, corrupt, delay):
    """``swarm launch --driver gateway --drop --corrupt --delay`` (3 seeds, 4 robots): every run completes with the
    per-configuration table and P_f of the fault-free run of its seed, and no robot moves twice in a step."""
    from inchworm.bench.faults_gateway import gateway_fault_row

    row = gateway_fault_row(drop, corrupt, delay, seeds=[0, 1, 2], robots=4, configs=2)
    assert row == {"drop": drop, "corrupt": corrupt, "delay": delay, "runs": 3, "completed": 3, "identical": 3,
                   "max_executions_per_step": 1}


def test_launch_rejects_bad_fault_options_naming_the_flag(tmp_path):
    for args, message in ((["--driver=gateway", "--drop=1.5"], "--drop must be a probability in [0, 1], got 1.5"),
                          (["--driver=gateway", "--corrupt=-0.1"], "--corrupt must be a probability"),
                          (["--driver=gateway", "--delay=inf"], "--delay must be a finite number of seconds"),
                          (["--drop=0.1"], "--drop is a fault of the emulated robots' radio and links: it needs the gateway driver")):
        proc = subprocess.run([sys.executable, "-m", "swarm_cli.main", "demo", "--no-record", *args],
                              capture_output=True, text=True, timeout=60, cwd=tmp_path)
        assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr, proc.stderr


def test_an_idle_agent_whose_link_dies_reports_its_robot_lost_and_exits_3(tmp_path):
    def config(ids):
        return GatewayConfig((Port("radio0", "emulated", tuple(ids)),))

    with emulated_site(tmp_path, 2, 3, config) as site:
        robot = site.ids[0]
        link = site.link("idle")
        agent = site.agent(robot, "idle", stderr=subprocess.PIPE, text=True)
        wait_for(lambda: f"swarm/idle/alive/robot/{robot}" in alive_now(site.session, "swarm/idle/alive/**"), 30, "the agent")
        link.kill()  # the agent is idle: no command in flight
        killed = time.monotonic()
        assert agent.wait(timeout=10) == 3
        assert time.monotonic() - killed < 3.0
        wait_for(lambda: f"swarm/idle/alive/robot/{robot}" not in alive_now(site.session, "swarm/idle/alive/**"), 5, "token gone")
        assert "the link process of port radio0 is gone" in agent.stderr.read()



# -- one process per port: its link and its robots' agents (``swarm agent --link``) ------------------------------


def _one_port(ids):
    return GatewayConfig((Port("radio0", "emulated", tuple(ids)),))


def _robot_tokens(session, run: str) -> set[str]:
    return alive_now(session, alive_wildcard(run))


def test_a_port_process_runs_its_link_and_agents_and_stops_cleanly(tmp_path):
    """``swarm agent --id <the port's robots> --link``: the robots answer through the link in the process; SIGTERM ends
    it with status 0, every token gone and the link's counters printed."""
    with emulated_site(tmp_path, 3, 4, _one_port) as site:
        run = "porthost"
        host = site.agent(",".join(map(str, site.ids)), run, "--link", stderr=subprocess.PIPE, text=True)
        wait_for(lambda: len(_robot_tokens(site.session, run)) == 3, 20, "the three agents' tokens")
        assert alive_now(site.session, link_alive_key(run, "radio0")), "the link's token, from the same process"
        host.send_signal(signal.SIGTERM)
        _, err = host.communicate(timeout=20)
        assert host.returncode == 0, err[-2000:]
        assert "swarm link: port radio0:" in err and "ERROR" not in err and "Traceback" not in err, err[-2000:]
        assert _robot_tokens(site.session, run) == set() and not alive_now(site.session, link_alive_key(run, "radio0"))


def test_a_port_process_whose_radio_dies_reports_its_robots_lost_and_exits_3(tmp_path):
    """The radio (the emulator's pty) disappears under a port process: its link stops, the agents see the link's token
    go and report their robots lost; the process ends with status 3, no traceback, every token gone."""
    with emulated_site(tmp_path, 3, 5, _one_port) as site:
        run = "radiodies"
        host = site.agent(",".join(map(str, site.ids)), run, "--link", stderr=subprocess.PIPE, text=True)
        wait_for(lambda: len(_robot_tokens(site.session, run)) == 3, 20, "the three agents' tokens")
        emulator = site.procs[0]
        emulator.kill()
        emulator.wait()
        _, err = host.communicate(timeout=20)
        assert host.returncode == 3, err[-2000:]
        assert "read failed" in err and err.count("lost: robot") == 3 and "Traceback" not in err, err[-2000:]
        assert _robot_tokens(site.session, run) == set()


@pytest.mark.parametrize(("args", "message"), [
    (["--id=0", "--driver=sim", "--pose=0,0,0", "--link"], "--link runs the link of a port of the gateway: it needs --driver gateway"),
    (["--driver=gateway", "--link"], "robots [2, 3] of port radio0 are robots of the run but not hosted by this process (--id 0-1)"),
])
def test_link_in_an_agent_process_needs_the_gateway_and_every_robot_of_the_port(tmp_path, capsys, args, message):
    config = tmp_path / "gw.json"
    _one_port([0, 1, 2, 3]).save(config)
    assert agent_main(["--id=0-1", "--ids=0-3", "--run=r", "--hub=tcp/127.0.0.1:9", f"--gateway-config={config}", *args]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err, err


def test_a_port_process_whose_device_cannot_be_opened_exits_2_naming_it(tmp_path):
    """The device is opened before any agent declares itself: a wrong device is one line and status 2, no agent appears."""
    config = tmp_path / "gw.json"
    GatewayConfig((Port("radio0", str(tmp_path / "ttyNOPE"), (0, 1)),)).save(config)
    hub_session, member, hub = open_loopback_hub()
    with hub_session, open_session(member) as session:
        proc = subprocess.run(PY + ["swarm_cli.agent", "--id=0,1", "--ids=0,1", "--run=nodevice", f"--hub={hub}",
                                    "--driver=gateway", f"--gateway-config={config}", "--link"], capture_output=True, text=True, timeout=60)
        assert alive_now(session, alive_wildcard("nodevice")) == set()
    assert proc.returncode == 2 and f"cannot open serial device {tmp_path / 'ttyNOPE'}" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
