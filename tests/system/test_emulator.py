"""Emulated robots (robot_agent/emulator.py) driven through their real pty, as a link process would.

Each test opens the emulator's slave device (raw mode), writes frames and reads the answers
with a ``FrameDecoder``; the robot side must behave as docs/gateway-protocol.md says and draw
the same random numbers as a ``SimDriver``. The last tests run ``swarm emulate-robots`` as a
real subprocess.
"""

from __future__ import annotations

import json
import math
import os
import queue
import select
import signal
import subprocess
import sys
import threading
import time
import tty
from pathlib import Path

import numpy as np
import pytest

from robot_agent.driver import SimDriver
from robot_agent.emulator import EmulatedWorld, FaultPlan, PortEmulator, TruthPublisher
from runtime.gateway.config import Calibration, GatewayConfig
from runtime.gateway.frames import (
    BROADCAST,
    MAX_ENTRIES,
    EmptyBody,
    ErrorBody,
    ErrorCode,
    Frame,
    FrameDecoder,
    FrameType,
    HeartbeatBody,
    MotionBody,
    RefusalBody,
    RefusalCode,
    RunBody,
    StepBody,
    encode_frame,
)
from runtime.models.config import ModelConfig
from runtime.models.trajectory import Trajectory
from runtime.wire.keys import coord_alive_key, truth_wildcard
from runtime.wire.messages import MotionCommand, TruthMessage, decode, message_key

ROOT = Path(__file__).resolve().parents[2]
SEED = 7
IDS = [0, 1, 2, 5]  # robot 5 is in the run but behind no emulated port: sensed, never moved
POSES = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 1.0], [0.0, 0.25, -2.0], [0.15, 0.15, 0.5]])


def f32(x: float) -> float:
    return float(np.float32(x))


class Link:
    """The gateway end of an emulated port: the pty slave opened like a serial device."""

    def __init__(self, device: str) -> None:
        self.fd = os.open(device, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)
        self.decoder = FrameDecoder()
        self.inbox: list[Frame] = []

    def close(self) -> None:
        os.close(self.fd)

    def write(self, data: bytes) -> None:
        os.write(self.fd, data)

    def send(self, robot: int, seq: int, kind: FrameType, body) -> Frame:
        frame = Frame.of(robot, seq, kind, body)
        self.write(encode_frame(frame))
        return frame

    def _pump(self, timeout: float) -> None:
        ready, _, _ = select.select([self.fd], [], [], max(timeout, 0.0))
        if ready:
            self.inbox += self.decoder.feed(os.read(self.fd, 4096))

    def expect(self, n: int, timeout: float = 2.0) -> list[Frame]:
        """The next ``n`` frames (fails after ``timeout`` s)."""
        deadline = time.monotonic() + timeout
        while len(self.inbox) < n and time.monotonic() < deadline:
            self._pump(deadline - time.monotonic())
        assert len(self.inbox) >= n, f"expected {n} frames within {timeout} s, got {self.inbox}"
        out, self.inbox = self.inbox[:n], self.inbox[n:]
        return out

    def silence(self, duration: float) -> list[Frame]:
        """Whatever arrives within ``duration`` s (normally nothing)."""
        deadline = time.monotonic() + duration
        while time.monotonic() < deadline:
            self._pump(deadline - time.monotonic())
        out, self.inbox = self.inbox, []
        return out


def kinds(frames: list[Frame]) -> list[tuple[int, int, str]]:
    return [(f.robot, f.seq, FrameType(f.type).name) for f in frames]


@pytest.fixture
def cfg() -> ModelConfig:
    return ModelConfig()


def make_port(cfg, robots=(0, 1, 2), *, motion_time_s=0.0, heartbeat_timeout_s=1.0, faults=None, ids=IDS, poses=POSES, calibration=None):
    world = EmulatedWorld(ids, poses, cfg, SEED, calibration, motion_time_s, heartbeat_timeout_s)
    events: list[dict] = []
    port = PortEmulator(world, "radio0", robots, faults, on_event=events.append)
    return world, port, events


@pytest.fixture
def emulated(cfg, request):
    """(world, port, link, events); options of ``make_port`` come as the indirect parameter."""
    opts = getattr(request, "param", {})
    world, port, events = make_port(cfg, **opts)
    link = Link(port.device)
    try:
        yield world, port, link, events
    finally:
        link.close()
        port.close()
    assert_no_emulator_threads()


def assert_no_emulator_threads(timeout: float = 1.0) -> None:
    """Every reader, delay and motion thread of the closed emulators has ended."""
    deadline = time.monotonic() + timeout
    while (alive := [t.name for t in threading.enumerate() if t.name.startswith("emulator-")]) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert alive == []


def test_command_accepted_then_done_with_the_pose_a_simdriver_reaches(emulated, cfg):
    world, port, link, events = emulated
    sim = SimDriver(1, IDS, POSES[1], cfg, SEED)
    for step, seq, (turn, drive) in [(1, 1, (0.3, 0.12)), (2, 2, (-1.1, 0.05)), (3, 3, (0.0, 0.0))]:
        link.send(1, seq, FrameType.COMMAND, MotionBody(step, turn, drive))
        accepted, done = link.expect(2)
        assert (accepted.robot, accepted.seq, accepted.type, accepted.body()) == (1, seq, FrameType.ACCEPTED, StepBody(step))
        assert (done.robot, done.seq, done.type, done.body()) == (1, seq, FrameType.DONE, StepBody(step))
        expected = sim.execute(MotionCommand(run="t", step=step, robot=1, config=1, turn_rad=f32(turn), drive_m=f32(drive)))
        np.testing.assert_array_equal(world.pose(1), expected)  # same stream, same float32 command: same numbers
    executed = [e for e in events if e["event"] == "executed"]
    assert [e["step"] for e in executed] == [1, 2, 3] and executed[-1]["pose"] == world.pose(1).tolist()
    np.testing.assert_array_equal(world.pose(0), POSES[0])  # the others did not move
    assert port.executed(1) == 3


def test_retransmitted_command_is_answered_again_and_executed_once(emulated):
    world, port, link, events = emulated
    frame = link.send(0, 5, FrameType.COMMAND, MotionBody(1, 0.2, 0.1))
    assert kinds(link.expect(2)) == [(0, 5, "ACCEPTED"), (0, 5, "DONE")]
    pose = world.pose(0)
    link.write(encode_frame(frame))  # the DONE was lost: same frame, same SEQ
    assert kinds(link.expect(1)) == [(0, 5, "DONE")]
    link.send(0, 1, FrameType.COMMAND, MotionBody(1, 0.2, 0.1))  # a restarted gateway: same step, new SEQ
    assert kinds(link.expect(1)) == [(0, 1, "DONE")]
    assert link.silence(0.05) == []
    assert port.executed(0) == 1
    np.testing.assert_array_equal(world.pose(0), pose)
    assert [e["type"] for e in events if e["event"] == "duplicate"] == ["COMMAND", "COMMAND"]
    link.send(0, 2, FrameType.COMMAND, MotionBody(0, 0.2, 0.1))  # lower step
    (refused,) = link.expect(1)
    assert refused.type == FrameType.REFUSED and refused.body().code == RefusalCode.OTHER
    assert "stale step" in refused.body().reason
    link.send(0, 3, FrameType.COMMAND, MotionBody(2, 0.0, -0.1))  # a robot's own limits: no driving backwards
    (refused,) = link.expect(1)
    assert refused.body().code == RefusalCode.LIMITS and port.executed(0) == 1


def test_observation_parts_and_duplicate_observe_does_not_sense_again(cfg):
    ids = list(range(30))  # a 6 x 5 grid, 5 cm apart: robot 3 sees all 29 others (two parts)
    poses = np.array([[0.05 * (i % 6), 0.05 * (i // 6), 0.1 * i] for i in ids])
    world, port, events = make_port(cfg, robots=(0, 3), ids=ids, poses=poses)
    heard: list[tuple[int, int]] = []
    world.add_truth_listener(lambda robot, step, pose: heard.append((robot, step)))
    sim = SimDriver(3, ids, poses[3], cfg, SEED)
    peers = {r: poses[i] for i, r in enumerate(ids)}
    link = Link(port.device)
    try:
        for step, seq in [(0, 1), (1, 2)]:
            link.send(3, seq, FrameType.OBSERVE, StepBody(step))
            parts = link.expect(2)
            bodies = [p.body() for p in parts]
            assert [(p.robot, p.seq, p.type) for p in parts] == [(3, seq, FrameType.OBSERVATION)] * 2
            assert [(b.step, b.part, b.parts) for b in bodies] == [(step, 0, 2), (step, 1, 2)]
            assert len(bodies[0].entries) == MAX_ENTRIES and len(bodies[1].entries) == 29 - MAX_ENTRIES
            assert bodies[0].stamp_ms == bodies[1].stamp_ms
            got = [e for b in bodies for e in b.entries]
            obs_ids, ranges, bearings = sim.sense(peers)
            assert [e[0] for e in got] == obs_ids.tolist()
            np.testing.assert_array_equal([e[1] for e in got], ranges.astype(np.float32))
            np.testing.assert_array_equal([e[2] for e in got], bearings.astype(np.float32))
            # a retransmission and a new SEQ for the same step: the stored parts, no new sensing
            link.send(3, seq, FrameType.OBSERVE, StepBody(step))
            assert [f.payload for f in link.expect(2)] == [p.payload for p in parts]
            link.send(3, 100 + seq, FrameType.OBSERVE, StepBody(step))
            again = link.expect(2)
            assert [f.seq for f in again] == [100 + seq] * 2 and [f.payload for f in again] == [p.payload for p in parts]
        assert heard == [(3, 0), (3, 1)]  # the truth of a step is told once, before the answer
        assert world.truth(3)[0] == 1
        link.send(3, 9, FrameType.OBSERVE, StepBody(0))  # an older step than the last observed
        (error,) = link.expect(1)
        assert error.type == FrameType.ERROR and error.body().code == ErrorCode.OTHER and "stale" in error.body().text
        assert sum(e["event"] == "duplicate" for e in events) == 4
    finally:
        link.close()
        port.close()


def test_observation_with_no_neighbour_is_one_empty_part(cfg):
    world, port, _ = make_port(cfg, robots=(0,), ids=[0, 1], poses=np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]]))
    link = Link(port.device)
    try:
        link.send(0, 1, FrameType.OBSERVE, StepBody(4))
        (part,) = link.expect(1)
        body = part.body()
        assert (body.step, body.part, body.parts, body.entries) == (4, 0, 1, ())
    finally:
        link.close()
        port.close()


def test_miscalibrated_robot_drives_scaled_and_measures_biased(cfg):
    cal = {0: Calibration(range_bias_m=0.02, bearing_offset_rad=3.0, motion_scale=0.5)}
    world, port, _ = make_port(cfg, robots=(0,), calibration=cal)
    sim = SimDriver(0, IDS, POSES[0], cfg, SEED)
    link = Link(port.device)
    try:
        link.send(0, 1, FrameType.COMMAND, MotionBody(1, 0.25, 0.2))
        link.expect(2)
        expected = sim.execute(MotionCommand(run="t", step=1, robot=0, config=1, turn_rad=f32(0.25), drive_m=f32(0.2) * 0.5))
        np.testing.assert_array_equal(world.pose(0), expected)
        link.send(0, 2, FrameType.OBSERVE, StepBody(1))
        entries = link.expect(1)[0].body().entries
        peers = {r: world.pose(r) for r in IDS}
        ids, ranges, bearings = sim.sense(peers)
        assert [e[0] for e in entries] == ids.tolist()
        np.testing.assert_allclose([e[1] for e in entries], ranges + 0.02, atol=1e-6)
        np.testing.assert_allclose([e[2] for e in entries], np.remainder(bearings + 3.0 + np.pi, 2 * np.pi) - np.pi, atol=1e-6)
    finally:
        link.close()
        port.close()


@pytest.mark.parametrize("emulated", [{"motion_time_s": 0.6, "heartbeat_timeout_s": 0.25}], indirect=True)
def test_heartbeat_watchdog_stops_the_robot_and_frames_revive_it(emulated):
    world, port, link, events = emulated
    assert link.silence(0.35) == []  # the watchdog starts with the first frame: an idle port is no timeout
    assert not any(e["event"] == "heartbeat_timeout" for e in events)
    link.send(0, 1, FrameType.HEARTBEAT, HeartbeatBody(123456))
    (ack,) = link.expect(1)
    assert (ack.type, ack.seq, ack.body()) == (FrameType.HEARTBEAT_ACK, 1, HeartbeatBody(123456))
    link.send(0, 2, FrameType.COMMAND, MotionBody(1, 0.5, 0.2))
    assert kinds(link.expect(1)) == [(0, 2, "ACCEPTED")]
    (aborted,) = link.expect(1, timeout=1.0)  # silence: the motion in progress is aborted
    assert (aborted.seq, aborted.type, aborted.body().step, aborted.body().code) == (2, FrameType.REFUSED, 1, RefusalCode.NO_HEARTBEAT)
    np.testing.assert_array_equal(world.pose(0), POSES[0])  # stopped where it was
    assert [e["robot"] for e in events if e["event"] == "heartbeat_timeout"] == [0]
    link.send(0, 3, FrameType.COMMAND, MotionBody(1, 0.5, 0.2))  # reaches the stopped robot: refused
    (refused,) = link.expect(1)
    assert refused.body().code == RefusalCode.NO_HEARTBEAT and port.executed(0) == 0
    link.send(0, 4, FrameType.HEARTBEAT, HeartbeatBody(1))
    assert kinds(link.expect(1)) == [(0, 4, "HEARTBEAT_ACK")]
    link.send(0, 5, FrameType.COMMAND, MotionBody(1, 0.5, 0.2))  # revived: runs, kept alive by heartbeats
    assert kinds(link.expect(1)) == [(0, 5, "ACCEPTED")]
    for k in range(8):
        time.sleep(0.1)
        link.send(0, 6 + k, FrameType.HEARTBEAT, HeartbeatBody(k))
    answers = link.expect(9)
    assert kinds(answers).count((0, 5, "DONE")) == 1 and port.executed(0) == 1
    assert any(e["event"] == "heartbeat_recovered" for e in events)


@pytest.mark.parametrize("emulated", [{"motion_time_s": 0.5}], indirect=True)
def test_broadcast_estop_answered_by_every_robot_and_latched_until_reset(emulated):
    world, port, link, events = emulated
    link.send(0, 1, FrameType.COMMAND, MotionBody(1, 0.4, 0.2))
    assert kinds(link.expect(1)) == [(0, 1, "ACCEPTED")]
    before = time.time_ns()
    link.send(BROADCAST, 9, FrameType.ESTOP, EmptyBody())
    answers = link.expect(4)
    assert kinds(answers) == [(0, 1, "REFUSED"), (0, 9, "ESTOPPED"), (1, 9, "ESTOPPED"), (2, 9, "ESTOPPED")]
    assert answers[0].body().code == RefusalCode.ESTOPPED
    estops = [e for e in events if e["event"] == "estop"]
    assert [e["robot"] for e in estops] == [0, 1, 2] and all(e["time_ns"] >= before and e["broadcast"] for e in estops)
    assert link.silence(0.6) == []  # the aborted motion never completes
    np.testing.assert_array_equal(world.pose(0), POSES[0])
    link.send(1, 1, FrameType.COMMAND, MotionBody(1, 0.0, 0.1))
    assert link.expect(1)[0].body() == RefusalBody(1, RefusalCode.ESTOPPED, "emergency stop latched (RESET clears it)")
    link.send(1, 2, FrameType.ESTOP, EmptyBody())  # idempotent
    assert kinds(link.expect(1)) == [(1, 2, "ESTOPPED")]
    link.send(1, 3, FrameType.RESET, EmptyBody())
    assert kinds(link.expect(1)) == [(1, 3, "RESET_ACK")]
    link.send(1, 4, FrameType.COMMAND, MotionBody(1, 0.0, 0.1))  # the refused step, now executed
    assert kinds(link.expect(2, timeout=2.0)) == [(1, 4, "ACCEPTED"), (1, 4, "DONE")]
    link.send(2, 1, FrameType.COMMAND, MotionBody(1, 0.0, 0.1))  # robot 2 is still latched
    assert link.expect(1)[0].body().code == RefusalCode.ESTOPPED
    assert (port.executed(0), port.executed(1), port.executed(2)) == (0, 1, 0)
    assert port.estopped(0) and not port.estopped(1) and port.estopped(2)


def test_garbage_between_frames_does_not_disturb_the_robots(emulated):
    world, port, link, events = emulated
    hb = lambda robot, seq: encode_frame(Frame.of(robot, seq, FrameType.HEARTBEAT, HeartbeatBody(seq)))  # noqa: E731
    bad_crc = bytearray(hb(0, 50))
    bad_crc[-1] ^= 0xFF
    link.write(b"\x00\xa5\xff\x13\xa5" + hb(0, 1) + bytes(range(0, 250, 7)) + bytes(bad_crc) + hb(1, 2) + b"\xa5\xc8\x00")
    assert kinds(link.expect(2)) == [(0, 1, "HEARTBEAT_ACK"), (1, 2, "HEARTBEAT_ACK")]
    time.sleep(0.05)  # the partial frame (LEN 200) is given up after 20 ms of quiet
    link.write(hb(2, 3))
    assert kinds(link.expect(1)) == [(2, 3, "HEARTBEAT_ACK")]
    link.write(encode_frame(Frame(0, 4, 0x42, b"")))  # unknown type
    link.write(encode_frame(Frame(0, 5, FrameType.COMMAND, b"\x01\x02\x03")))  # bad body
    link.write(encode_frame(Frame(0, 6, FrameType.DONE, b"\x01\x00\x00\x00")))  # an answer type sent to a robot
    link.write(hb(7, 7))  # a robot behind another port: ignored
    errors = link.expect(3)
    assert [(f.seq, f.body().code) for f in errors] == [(4, ErrorCode.UNKNOWN_TYPE), (5, ErrorCode.BAD_BODY), (6, ErrorCode.UNKNOWN_TYPE)]
    assert "MotionBody" in errors[1].body().text
    assert link.silence(0.05) == []
    stats = port.stats()
    assert stats.crc_errors >= 1 and stats.length_errors >= 2 and stats.foreign_frames == 1
    assert isinstance(errors[0].body(), ErrorBody)


@pytest.mark.parametrize("emulated", [{"motion_time_s": 0.4, "faults": FaultPlan(drop_tx=frozenset({0}))}], indirect=True)
def test_dropped_first_accepted_comes_with_the_retransmission(emulated):
    world, port, link, events = emulated
    frame = link.send(0, 1, FrameType.COMMAND, MotionBody(1, 0.1, 0.1))
    assert link.silence(0.15) == []  # ACCEPTED was lost
    link.write(encode_frame(frame))  # the gateway retransmits after ack_timeout_s
    assert kinds(link.expect(1)) == [(0, 1, "ACCEPTED")]
    assert kinds(link.expect(1, timeout=1.0)) == [(0, 1, "DONE")]
    assert port.executed(0) == 1 and port.stats().tx_dropped == 1
    assert [(e["kind"], e["index"]) for e in events if e["event"] == "fault"] == [("drop_tx", 0)]


def test_dropped_rx_corrupted_and_delayed_frames(cfg):
    plan = FaultPlan(drop_rx=frozenset({0}), delay_s=0.2)
    _, port, events = make_port(cfg, faults=plan)
    link = Link(port.device)
    try:
        link.send(0, 1, FrameType.HEARTBEAT, HeartbeatBody(1))  # rx frame 0: dropped
        assert link.silence(0.25) == []
        start = time.monotonic()
        link.send(0, 2, FrameType.HEARTBEAT, HeartbeatBody(2))
        assert kinds(link.expect(1)) == [(0, 2, "HEARTBEAT_ACK")]
        assert time.monotonic() - start >= 0.19
        assert port.stats().rx_dropped == 1 and port.stats().tx_delayed == 1
    finally:
        link.close()
        port.close()
    _, port, events = make_port(cfg, faults=FaultPlan(corrupt_prob=1.0, seed=3))
    link = Link(port.device)
    try:
        for seq in range(1, 6):
            link.send(0, seq, FrameType.HEARTBEAT, HeartbeatBody(seq))
        assert link.silence(0.2) == []  # every answer has a flipped byte: none passes the CRC
        assert port.stats().tx_corrupted == 5
        assert sum(e["event"] == "fault" and e["kind"] == "corrupt" for e in events) == 5
    finally:
        link.close()
        port.close()
    assert_no_emulator_threads()


def test_truth_published_at_start_on_observe_and_when_the_coordinator_appears(cfg):
    from runtime.wire.transport import declare_token, open_loopback_hub, open_session, subscribe_queue

    run = "emu-truth"
    hub, member, _ = open_loopback_hub()
    world, port, _ = make_port(cfg, robots=(0, 1))
    link = Link(port.device)
    with hub, open_session(member) as session:
        _, inbox = subscribe_queue(hub, truth_wildcard(run))

        def truths(n: int) -> list[TruthMessage]:
            return [decode(inbox.get(timeout=3.0)[1], TruthMessage) for _ in range(n)]

        probe = session.declare_publisher(message_key(TruthMessage(run=run, step=0, robot=0, pose=[0.0, 0.0, 0.0])))
        deadline = time.monotonic() + 5
        while not probe.matching_status.matching:  # the hub's subscription is known to the client session
            assert time.monotonic() < deadline, "the truth subscription never reached the client session"
            time.sleep(0.005)
        probe.undeclare()
        publisher = TruthPublisher(world, session, run)
        try:
            publisher.start()
            first = sorted(truths(2), key=lambda m: m.robot)
            assert [(m.robot, m.step) for m in first] == [(0, 0), (1, 0)]
            assert first[1].pose == tuple(POSES[1])
            link.send(1, 1, FrameType.OBSERVE, StepBody(4))
            link.expect(1)
            (observed,) = truths(1)
            assert (observed.robot, observed.step) == (1, 4)
            token = declare_token(hub, coord_alive_key(run, 1))
            again = sorted(truths(2), key=lambda m: m.robot)
            assert [(m.robot, m.step) for m in again] == [(0, 0), (1, 4)]
            token.undeclare()
            with pytest.raises(queue.Empty):
                inbox.get(timeout=0.1)
        finally:
            publisher.close()
            link.close()
            port.close()
    assert_no_emulator_threads()


# -- the CLI as a real subprocess ------------------------------------------------------------


def _write_inputs(tmp_path: Path) -> tuple[Path, Path]:
    config = GatewayConfig.from_json({
        "ports": [{"name": "radio0", "device": "/dev/null", "robots": [0, 1]}, {"name": "radio1", "device": "/dev/null", "robots": [2]}],
        "timing": {"heartbeat_timeout_s": 5.0},
    })
    config_path, traj_path = tmp_path / "gateway.json", tmp_path / "traj.json"
    config.save(config_path)
    Trajectory(np.array(IDS), POSES, POSES[None, :, :2] + 0.1).save(traj_path)
    return config_path, traj_path


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "swarm_cli.emulate", *args]


def test_cli_writes_a_config_with_working_pty_paths_and_exits_0_on_sigterm(tmp_path):
    import serial

    config_path, traj_path = _write_inputs(tmp_path)
    out, events_path = tmp_path / "gateway.pty.json", tmp_path / "events.jsonl"
    proc = subprocess.Popen(
        _cli("--config", str(config_path), "--trajectory", str(traj_path), "--seed", str(SEED), "--write-config", str(out),
             "--events", str(events_path), "--json"),
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        deadline = time.monotonic() + 20
        while not out.exists():
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "no --write-config file within 20 s"
            time.sleep(0.05)
        written = GatewayConfig.load(out)
        devices = {p.name: p.device for p in written.ports}
        assert all(d.startswith("/dev/pts/") for d in devices.values())
        assert written.timing.heartbeat_timeout_s == 5.0 and [p.robots for p in written.ports] == [(0, 1), (2,)]
        with serial.Serial(devices["radio1"], 115200, timeout=0.05) as port:  # like a real serial device
            decoder, got = FrameDecoder(), []
            port.write(encode_frame(Frame.of(2, 1, FrameType.COMMAND, MotionBody(1, 0.3, 0.1))))
            while len(got) < 2 and time.monotonic() < deadline:
                got += decoder.feed(port.read(64))
            assert kinds(got) == [(2, 1, "ACCEPTED"), (2, 1, "DONE")]
        link = Link(devices["radio0"])
        try:
            link.send(1, 1, FrameType.HEARTBEAT, HeartbeatBody(42))
            assert kinds(link.expect(1)) == [(1, 1, "HEARTBEAT_ACK")]
        finally:
            link.close()
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=10)
        assert proc.returncode == 0, stderr
        lines = stdout.splitlines()
        assert lines[0] == f"port radio0: {devices['radio0']} (robots 0,1)"
        assert lines[1] == f"port radio1: {devices['radio1']} (robots 2)"
        assert json.loads(lines[-1]) == {"ports": devices, "config": str(out)}
        events = [json.loads(line) for line in events_path.read_text().splitlines()]
        (executed,) = [e for e in events if e["event"] == "executed"]
        sim = SimDriver(2, IDS, POSES[2], ModelConfig(), SEED)
        expected = sim.execute(MotionCommand(run="t", step=1, robot=2, config=1, turn_rad=f32(0.3), drive_m=f32(0.1)))
        assert (executed["port"], executed["robot"], executed["step"]) == ("radio1", 2, 1)
        np.testing.assert_array_equal(executed["pose"], expected)
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
            proc.communicate()


def test_cli_rejects_config_robots_missing_from_the_trajectory(tmp_path):
    config_path, _ = _write_inputs(tmp_path)
    traj_path = tmp_path / "small.json"
    Trajectory(np.array([0, 1]), POSES[:2], POSES[None, :2, :2]).save(traj_path)
    result = subprocess.run(_cli("--config", str(config_path), "--trajectory", str(traj_path)),
                            cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert result.returncode == 2
    assert "robots [2] of the gateway config" in result.stderr and "not in the trajectory" in result.stderr


def test_run_forgets_the_step_memory_once_per_epoch(emulated):
    """A second run on the same robots: RUN with a new epoch clears the steps, a repeated RUN only answers."""
    world, port, link, events = emulated
    link.send(0, 1, FrameType.COMMAND, MotionBody(3, 0.1, 0.05))
    assert kinds(link.expect(2)) == [(0, 1, "ACCEPTED"), (0, 1, "DONE")]
    link.send(0, 2, FrameType.COMMAND, MotionBody(1, 0.1, 0.05))  # the next run's step 1 without RUN: stale
    (refused,) = link.expect(1)
    assert refused.type == FrameType.REFUSED and "stale step 1" in refused.body().reason
    link.send(0, 3, FrameType.RUN, RunBody(77))
    (ack,) = link.expect(1)
    assert (ack.seq, ack.type, ack.body()) == (3, FrameType.RUN_ACK, RunBody(77))
    link.send(0, 4, FrameType.COMMAND, MotionBody(1, 0.1, 0.05))
    assert kinds(link.expect(2)) == [(0, 4, "ACCEPTED"), (0, 4, "DONE")]
    link.send(0, 5, FrameType.RUN, RunBody(77))  # a retransmitted RUN: answered, memory kept
    assert kinds(link.expect(1)) == [(0, 5, "RUN_ACK")]
    link.send(0, 6, FrameType.COMMAND, MotionBody(1, 0.1, 0.05))  # so step 1 is a duplicate, not executed again
    assert kinds(link.expect(1)) == [(0, 6, "DONE")]
    assert port.executed(0) == 2
    assert [(e["epoch"], e["previous"]) for e in events if e["event"] == "run"] == [(77, 0)]


@pytest.mark.parametrize("emulated", [{"motion_time_s": 5.0}], indirect=True)
def test_repeated_command_while_moving_is_answered_accepted_and_run_aborts_the_motion(emulated):
    world, port, link, events = emulated
    frame = link.send(1, 1, FrameType.COMMAND, MotionBody(1, 0.1, 0.05))
    assert kinds(link.expect(1)) == [(1, 1, "ACCEPTED")]
    link.write(encode_frame(frame))  # the link re-sends while the robot moves: ACCEPTED again, nothing else
    assert kinds(link.expect(1)) == [(1, 1, "ACCEPTED")]
    link.send(1, 2, FrameType.RUN, RunBody(5))  # a new run while moving: the motion stops, refused
    refused, ack = link.expect(2)
    assert (refused.seq, refused.type, refused.body().code) == (1, FrameType.REFUSED, RefusalCode.OTHER)
    assert (ack.type, ack.body()) == (FrameType.RUN_ACK, RunBody(5))
    assert port.executed(1) == 0 and [e["event"] for e in events].count("accepted") == 1


def test_physical_robots_collide_stall_and_stop_on_an_emergency_stop(cfg):
    """``--physics``: the robots of a step move together in the rigid-body world; DONE comes once it is still."""
    pytest.importorskip("pymunk")
    from robot_agent.emulator_physics import PhysicalEmulatedWorld
    from runtime.world.params import PhysicsParams

    poses = np.array([[0.0, 0.0, 0.0], [0.06, 0.0, math.pi], [0.0, 0.3, 0.0]])
    world = PhysicalEmulatedWorld([0, 1, 2], poses, cfg, SEED, PhysicsParams(), speed=2.0, heartbeat_timeout_s=30.0)
    port = PortEmulator(world, "radio0", (0, 1, 2))
    link = Link(port.device)
    try:
        link.send(0, 1, FrameType.COMMAND, MotionBody(1, 0.0, 0.2))
        link.send(1, 1, FrameType.COMMAND, MotionBody(1, 0.0, 0.2))
        frames = link.expect(4, timeout=20.0)  # head-on: both stall; the world is still after ~4.4 s of world time
        assert sorted(kinds(frames)) == [(0, 1, "ACCEPTED"), (0, 1, "DONE"), (1, 1, "ACCEPTED"), (1, 1, "DONE")]
        assert np.linalg.norm(world.pose(0)[:2] - world.pose(1)[:2]) == pytest.approx(0.022, abs=1e-3)
        ids, ranges, _ = world.sense(2)
        assert ids.tolist() == [0, 1] and np.all(ranges > 0.25)
        link.send(2, 2, FrameType.COMMAND, MotionBody(2, 0.0, 0.3))
        assert kinds(link.expect(1)) == [(2, 2, "ACCEPTED")]
        time.sleep(0.5)
        link.send(2, 3, FrameType.ESTOP, EmptyBody())
        answers = kinds(link.expect(2, timeout=5.0))
        assert answers == [(2, 2, "REFUSED"), (2, 3, "ESTOPPED")]
        time.sleep(0.5)
        assert 0.0 < world.pose(2)[0] < 0.1  # it started, then stopped within its deceleration
    finally:
        link.close()
        port.close()
        world.close()
    assert_no_emulator_threads()
