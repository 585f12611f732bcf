"""The distributed runtime with real processes on loopback: agents + coordinator over a Zenoh hub.

Every child is started here and stopped by its pid in ``finally`` (inchworm.processes.stop_all).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path

import msgpack
import numpy as np
import pytest
from waiting import wait_for

from coordinator.simulate import simulate
from inchworm.processes import stop_all
from runtime.models.trajectory import Trajectory, body_spacing, random_trajectory
from runtime.recording.mcap_log import read_messages, recording_info
from runtime.wire.keys import coord_key, robot_key, robot_wildcard, truth_key, truths_key
from runtime.wire.messages import (
    EstimateMessage,
    MotionCommand,
    ObservationReport,
    PlanMessage,
    Status,
    TruthMessage,
    decode,
    encode,
    message_key,
)
from runtime.wire.transport import open_loopback_hub, open_session, publish, subscribe
from swarm_cli.main import build_parser
from swarm_cli.options import model_config

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}


class Run:
    """A hub (this process), one agent process per robot (but the robots ``hosted``, which share one) and the
    coordinator process."""

    def __init__(self, tmp: Path, traj: Trajectory, method: str, seed: int, motion_time: float = 0.0, out: Path | None = None,
                 extra: tuple[str, ...] = (), hosted: tuple[int, ...] = (), model: tuple[str, ...] = ()) -> None:
        self.traj, self.method, self.seed, self.model = traj, method, seed, model
        self.run_id = f"t{uuid.uuid4().hex[:10]}"
        self.traj_file = tmp / "traj.json"
        traj.save(self.traj_file)
        self.result_file = tmp / "result.json"
        self.tmp, self.motion_time = tmp, motion_time
        self.agents: dict[int, subprocess.Popen] = {}
        self.coordinator: subprocess.Popen | None = None
        self.stderr: list[str] = []
        self.stdout: list[str] = []
        self._readers: list[threading.Thread] = []
        self._news = threading.Condition()  # notified on every coordinator output line and every message heard
        self.session = None
        self.out = out
        self.heard: list[tuple[str, bytes]] = []  # what the coordinator published on coord/* and robot/*/cmd
        self.recording = tmp / "run.mcap"  # never the repository's recordings/
        self.extra = list(extra)  # more coordinator options
        self.hosted = hosted

    def start(self) -> None:
        self.session, self.member, self.hub = open_loopback_hub()
        for key_expr in (coord_key(self.run_id, "plan"), coord_key(self.run_id, "estimate"), robot_wildcard(self.run_id, "cmd")):
            subscribe(self.session, key_expr, self._hear)
        ids = ",".join(str(int(i)) for i in self.traj.ids)
        common = [f"--run={self.run_id}", f"--hub={self.hub}", f"--seed={self.seed}", *self.model]  # model: agents' and coordinator's
        for robot, pose in zip(self.traj.ids, self.traj.initial_poses, strict=True):
            if int(robot) in self.hosted:
                continue
            log = open(self.tmp / f"agent{robot}.log", "w")
            self.agents[int(robot)] = subprocess.Popen(
                [sys.executable, "-m", "swarm_cli.agent", f"--id={robot}", f"--ids={ids}", f"--motion-time={self.motion_time}",
                 f"--pose={','.join(repr(float(v)) for v in pose)}", *common],
                stdout=log, stderr=subprocess.STDOUT, cwd=REPO, env=ENV,
            )
        if self.hosted:  # one process, poses from the trajectory file
            host = subprocess.Popen(
                [sys.executable, "-m", "swarm_cli.agent", f"--id={','.join(map(str, self.hosted))}", f"--ids={ids}",
                 f"--motion-time={self.motion_time}", f"--trajectory={self.traj_file}", *common],
                stdout=open(self.tmp / "agents.log", "w"), stderr=subprocess.STDOUT, cwd=REPO, env=ENV,
            )
            self.agents.update(dict.fromkeys(self.hosted, host))
        self.coordinator = subprocess.Popen(
            [sys.executable, "-m", "swarm_cli.coordinator_cmd", f"--trajectory={self.traj_file}", f"--method={self.method}",
             f"--result={self.result_file}", "--step-timeout=5", "--start-timeout=30", f"--record={self.recording}", *common,
             *([f"--out={self.out}"] if self.out else []), *self.extra],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO, env=ENV,
        )
        for stream, lines in ((self.coordinator.stdout, self.stdout), (self.coordinator.stderr, self.stderr)):
            self._readers.append(threading.Thread(target=self._read, args=(stream, lines), daemon=True))
            self._readers[-1].start()

    def _hear(self, key: str, payload: bytes) -> None:
        with self._news:
            self.heard.append((key, payload))
            self._news.notify_all()

    def _read(self, stream, lines: list[str]) -> None:
        for line in stream:
            with self._news:
                lines.append(line)
                self._news.notify_all()
        with self._news:  # EOF: the coordinator is gone
            self._news.notify_all()

    def _wait(self, what: str, done: Callable[[], bool], timeout_s: float) -> None:
        """Until ``done()`` holds, woken by each new output line or message; fails if the coordinator exits first."""
        deadline = time.monotonic() + timeout_s
        with self._news:
            while not done():
                if self.coordinator.poll() is not None and not any(r.is_alive() for r in self._readers):
                    raise AssertionError(f"coordinator exited before {what}: {''.join(self.stderr)}")
                left = deadline - time.monotonic()
                assert left > 0, f"no {what} within {timeout_s} s: {''.join(self.stderr)}"
                self._news.wait(min(left, 1.0))

    def finish(self, timeout_s: float) -> str:
        """The coordinator's stdout once it exited."""
        self.coordinator.wait(timeout=timeout_s)
        for reader in self._readers:
            reader.join(timeout=5)
        return "".join(self.stdout)

    def wait_stderr(self, text: str, timeout_s: float) -> None:
        """Until the coordinator printed ``text`` on stderr (a readiness message)."""
        self._wait(repr(text), lambda: any(text in line for line in self.stderr), timeout_s)

    def wait_heard(self, what: str, predicate: Callable[[str, bytes], bool], timeout_s: float) -> None:
        """Until our subscriber heard a coordinator message satisfying ``predicate(key, payload)``."""
        self._wait(what, lambda: any(predicate(k, p) for k, p in list(self.heard)), timeout_s)

    def children(self) -> list[subprocess.Popen]:
        return [*{id(p): p for p in self.agents.values()}.values(), *([self.coordinator] if self.coordinator else [])]

    def stop(self) -> None:
        try:
            stop_all(self.children())
        finally:
            if self.session is not None:
                self.session.close()


def _alive_with(run_id: str) -> list[int]:
    """Pids of processes (zombies excluded) whose command line mentions ``run_id``."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if run_id in (entry / "cmdline").read_bytes().decode(errors="replace") and "Z" != (entry / "stat").read_text().split()[2]:
                    pids.append(int(entry.name))
            except OSError:
                pass
    return pids


def _in_process(traj: Trajectory, method: str, seed: int, model: tuple[str, ...] = ()):
    args = build_parser().parse_args(["coordinator", "--trajectory=x", "--run=x", "--hub=tcp/127.0.0.1:1", *model])
    return simulate(traj, method, model_config(args), localizer=args.localizer, seed=seed)


def _assert_same_as_in_process(run: Run) -> None:
    got = json.loads(run.result_file.read_text())
    ref = _in_process(run.traj, run.method, run.seed, run.model)
    assert len(got["steps"]) == len(ref.steps) > 0
    np.testing.assert_allclose(got["initial_truth"], ref.initial_truth, rtol=0, atol=1e-9)
    for s, r in zip(got["steps"], ref.steps, strict=True):
        np.testing.assert_allclose(s["poses"], r.estimate.poses, rtol=0, atol=1e-9)
        np.testing.assert_allclose(s["cov"], r.estimate.cov, rtol=0, atol=1e-9)
        np.testing.assert_allclose(s["truth"], r.truth, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got["final"], ref.configs[-1].estimate.poses, rtol=0, atol=1e-9)


@pytest.fixture(scope="module")
def completed(tmp_path_factory):
    """One short distributed run: 3 robots, 2 configurations, no-anchors."""
    seed = 4
    traj = random_trajectory(3, 2, np.random.default_rng(seed))
    tmp = tmp_path_factory.mktemp("dist")
    run = Run(tmp, traj, "no-anchors", seed, out=tmp / "plots")
    try:
        run.start()
        out = run.finish(60)
        agents_running = all(p.poll() is None for p in run.agents.values())
    finally:
        run.stop()
    return run, out, agents_running


def test_agents_and_coordinator_complete_a_run(completed):
    run, out, agents_running = completed
    assert run.coordinator.returncode == 0, "".join(run.stderr)
    assert agents_running, "an agent exited during the run"
    assert "P_f = " in out and "distributed" in out
    assert len([line for line in out.splitlines() if line.strip().startswith(("1 ", "2 "))]) == 2
    assert [p.returncode for p in run.agents.values()] == [0, 0, 0]  # SIGTERM: clean exit, session closed
    assert _alive_with(run.run_id) == []


def test_distributed_equals_in_process(completed):
    run, _, _ = completed
    _assert_same_as_in_process(run)


def test_coordinator_writes_the_plots(completed):
    run, out, _ = completed
    for name in ("trajectory.png", "errors.png"):
        path = run.out / name
        assert path.stat().st_size > 1000
        assert str(path) in out


def test_coordinator_publishes_plans_estimates_and_configs(completed):
    run, _, _ = completed
    got = json.loads(run.result_file.read_text())
    heard = [(key, decode(payload, key=key)) for key, payload in list(run.heard)]
    plans = [m for _, m in heard if isinstance(m, PlanMessage)]
    estimates = [m for _, m in heard if isinstance(m, EstimateMessage)]
    commands = [m for _, m in heard if isinstance(m, MotionCommand)]
    ids = [int(i) for i in run.traj.ids]
    # no-anchors: everyone moves in the configuration's one step; robots 1 and 2 drive 0.2-0.34 m into places 5.3-6.3 cm
    # apart, where their straight drives' ends touch with probability 1.7 % (configuration 1) and 5.5 % (2), so both
    # stop at staging points and go on in approach legs (robot 0 standing) until the rest of the way ends within
    # END_BOUND: two more legs in configuration 1, four in 2
    legs = (tuple(ids[1:]),)
    assert [(p.config, p.step, p.n_anchors, p.groups, p.leg) for p in plans] == [
        (1, 1, 0, (tuple(ids),), 0), (1, 2, 1, legs, 1), (1, 3, 1, legs, 2), (2, 4, 0, (tuple(ids),), 0), (2, 5, 1, legs, 1),
        (2, 6, 1, legs, 2), (2, 7, 1, legs, 3), (2, 8, 1, legs, 4)]
    assert sorted(m.step for m in estimates) == list(range(9))  # the initial estimate, then one per step
    by_step = {m.step: m for m in estimates}
    np.testing.assert_array_equal(by_step[0].to_estimate().poses, np.array(got["initial_estimate"]))
    for number, s in enumerate(got["steps"], start=1):
        est = by_step[number].to_estimate()
        assert est.ids.tolist() == ids
        np.testing.assert_array_equal(est.poses, np.array(s["poses"]))
        np.testing.assert_array_equal(est.cov, np.array(s["cov"]))
    assert {(m.step, m.config) for m in commands} == {(1, 1), (2, 1), (3, 1), (4, 2), (5, 2), (6, 2), (7, 2), (8, 2)}


def test_coordinator_records_the_run(completed):
    run, out, _ = completed
    assert f"recorded {run.recording}: " in out
    info = recording_info(run.recording)
    assert info["complete"] and info["undecodable"] == 0
    r, ids = run.run_id, [int(i) for i in run.traj.ids]
    run_channels = [c for c in info["channels"] if c["topic"].startswith("swarm/")]  # not derived views (/foxglove/...)
    counts = {c["topic"]: c["messages"] for c in run_channels}
    types = {c["topic"]: c["type"] for c in run_channels}
    # no-anchors, 3 robots, 2 configurations: 8 steps, everyone moves at the configurations' first, robots 1 and 2 at
    # their approach legs' (test_coordinator_publishes_plans_estimates_and_configs)
    assert counts[coord_key(r, "plan")] == 8 and counts[coord_key(r, "estimate")] == 9
    for robot in ids:
        for leaf in ("observe", "obs"):
            assert counts[robot_key(r, robot, leaf)] == 8, leaf
        assert counts[robot_key(r, robot, "cmd")] == (2 if robot == ids[0] else 8)
        assert types[robot_key(r, robot, "cmd")] == "MotionCommand" and types[robot_key(r, robot, "observe")] == "ObserveRequest"
        assert counts[robot_key(r, robot, "status")] >= 2  # accepted + done per command
        assert counts[truth_key(r, robot)] >= 9  # steps 0 to 8
    assert counts[truths_key(r)] == 8  # one truth set per motion step
    assert counts[coord_key(r, "checkpoint")] == 18  # the start, each plan and leg (8), each step (8), the end
    assert set(counts) == {coord_key(r, "plan"), coord_key(r, "estimate"), coord_key(r, "checkpoint"), truths_key(r),
                           *[robot_key(r, i, leaf) for i in ids for leaf in ("cmd", "observe", "status", "obs")],
                           *[truth_key(r, i) for i in ids]}
    meta = info["metadata"]["run"]
    assert meta["seed"] == run.seed and meta["method"] == run.method and meta["localizer"] == "paper"
    assert Trajectory.from_json(meta["trajectory"]).to_json() == run.traj.to_json()
    assert meta["model"]["bearing_sigma_rad"] == model_config(build_parser().parse_args(
        ["coordinator", "--trajectory=x", "--run=x", "--hub=tcp/127.0.0.1:1"])).bearing_sigma_rad
    # what our own subscriber heard (plans, estimates, commands) was recorded with identical bytes, in the same order
    recorded = [(k, p) for k, p, _t, _pub in read_messages(run.recording)]
    heard = list(run.heard)
    assert heard
    for key in {k for k, _ in heard}:
        assert [p for k, p in recorded if k == key] == [p for k, p in heard if k == key], key


def _wait_for_command(run: Run, timeout_s: float = 60.0) -> None:
    """Until our subscriber heard the coordinator's first MotionCommand (the run is moving)."""
    run.wait_heard("a motion command", lambda key, payload: key.endswith("/cmd"), timeout_s)


def _recorded(run: Run) -> list:
    return [decode(p) for _k, p, _t, _pub in read_messages(run.recording) if _k.startswith("swarm/")]


def _kill_an_agent_mid_run(tmp_path: Path, extra: tuple[str, ...] = ("--on-lost=abort",)) -> Run:
    """ref57 on 4 robots: once the coordinator has sent the first step's commands, SIGKILL robot 1's agent (a process
    of its own; robots 0, 2 and 3 share one, which saves two process starts per run: most of a run's CPU).

    Returns the finished (stopped) run; the caller asserts on it.
    """
    traj = random_trajectory(4, 4, np.random.default_rng(1))
    run = Run(tmp_path, traj, "ref57", 1, motion_time=0.3, extra=extra, hosted=(0, 2, 3))
    try:
        run.start()
        run.wait_stderr("agents alive", 60)
        _wait_for_command(run)  # the run is under way
        run.agents[1].send_signal(signal.SIGKILL)
        run.coordinator.wait(timeout=90)
        run.finish(10)
    finally:
        run.stop()
    return run


def _behind_robot_1(tmp_path: Path, x: float, seed: int, model: tuple[str, ...] = ()) -> tuple[Trajectory, Run, str]:
    """A distributed one-at-a-time run (``--json``) of robot 0 driving from (0, 0) to (0.3, 0), behind robot 1 going
    from (0.1, 0) to (``x``, 0), robot 2 aside, checked against the in-process run: (trajectory, run, its stdout)."""
    traj = Trajectory(np.arange(3), np.array([[0, 0, 0], [0.1, 0, 0], [0.0, 0.2, 0.0]]), np.array([[[0.3, 0.0], [x, 0.0], [0.05, 0.25]]]))
    return (traj, *_finished_as_in_process(tmp_path, traj, "one-at-a-time", seed, model))


def _finished_as_in_process(tmp_path: Path, traj: Trajectory, method: str, seed: int, model: tuple[str, ...]) -> tuple[Run, str]:
    """A distributed run of ``traj`` (``--json``) to its end, checked against the in-process run: (run, its stdout)."""
    run = Run(tmp_path, traj, method, seed, extra=("--json",), model=model)
    try:
        run.start()
        out = run.finish(60)
    finally:
        run.stop()
    assert run.coordinator.returncode == 0, "".join(run.stderr)
    _assert_same_as_in_process(run)
    return run, out


def test_a_target_at_risk_without_motion_is_stopped_short_as_in_process(tmp_path):
    """Robot 0 drives to 27 mm behind robot 1, which stands in its way: one-at-a-time is regrouped (robot 1 first, then
    robot 0), and robot 0's target is at risk even reached with no motion noise (5 mm of position error against 5 mm of
    room), so robot 0 stops short of its place at a safe distance (the longer way; before, it drove in and, with seed 4,
    the true bodies touched at the end of its step and stood touching through the last: 2 contacts); robot 1 arrives
    (robot 0 stages on its way while robot 1 approaches; before that, robot 1 stopped short too). The summary, the
    JSON and the recording say so, exactly as the in-process run: no contact."""
    traj, run, out = _behind_robot_1(tmp_path, 0.327, 4)
    ref = _in_process(traj, "one-at-a-time", 4)
    assert ref.contacts(0.011) == [] and ref.stopped_short() == [[0]] and ref.holds() == 0
    assert "config 1: steps regrouped for bodies (still 3)" in out and "contacts (bodies of radius 0.011 m): 0" in out
    assert "robots [0] stopped short of their targets" in out
    doc = json.loads(out.strip().splitlines()[-1])
    assert doc["robot_radius_m"] == 0.011 and doc["contacts"] == [] and doc["stopped_short"] == 1 and doc["holds"] == 0
    assert [leg["stopped_short"] for leg in doc["legs"]] == [[0]]
    assert not [topic for topic, _, _, _ in read_messages(run.recording) if topic.endswith("/sim/contact")]


NOISY = ("--turn-sigma-deg=60", "--drive-sigma-frac=1.0")  # motion noise x20 (x5.58 is the calibrated robots')


def test_contacts_of_noisy_robots_are_the_in_process_ones_and_recorded(tmp_path):
    """no-anchors on 4 robots at motion noise x20, 2 configurations (seed 18): the true bodies of robots 0 and 2, and 1
    and 3, touch at the last step (the second configuration's). (At x10 the runs tried no longer touch: 4 robots, seeds 19-89, and robot 0
    driving past robot 2 standing 5 cm beside its way, behind robot 1: leg ends within 1e-4, ways past standing robots
    and corrections, docs/bodies.md "Corrections, a stricter leg end and ways past standing robots".) The summary, the
    JSON and the recording's ContactMessages (and their Foxglove view) say so, exactly as the in-process run."""
    args = build_parser().parse_args(["coordinator", "--trajectory=x", "--run=x", "--hub=tcp/127.0.0.1:1", *NOISY])
    cfg = model_config(args)
    traj = random_trajectory(4, 2, np.random.default_rng(18), sensing_range=cfg.sensing_range_m, **body_spacing(cfg))
    run, out = _finished_as_in_process(tmp_path, traj, "no-anchors", 18, NOISY)
    ref = _in_process(traj, "no-anchors", 18, NOISY).contacts(0.011)
    last = len(json.loads(run.result_file.read_text())["steps"])
    assert [(c.step, c.config, c.a, c.b) for c in ref] == [(last, 1, 0, 2), (last, 1, 1, 3)]
    assert f"contacts (bodies of radius 0.011 m): {len(ref)}" in out
    doc = json.loads(out.strip().splitlines()[-1])
    assert doc["contacts"] == [{"step": c.step, "config": 2, "robots": [c.a, c.b], "distance_m": c.distance} for c in ref]
    msgs = [decode(payload) for topic, payload, _, _ in read_messages(run.recording) if topic.endswith("/sim/contact")]
    assert [(m.step, m.config, m.a, m.b, m.radius_m) for m in msgs] == [(c.step, 2, c.a, c.b, 0.011) for c in ref]
    assert [(m.distance_m, tuple(m.point)) for m in msgs] == [(c.distance, c.point) for c in ref]
    assert "/foxglove/contacts" in [t for t, _, _, _ in read_messages(run.recording, derived=True)]


def test_killed_agent_is_stopped_dropped_and_the_run_goes_on(tmp_path):
    run = _kill_an_agent_mid_run(tmp_path, extra=())
    out, err = "".join(run.stdout), "".join(run.stderr)
    assert run.coordinator.returncode == 0, err
    assert "robot 1 lost (liveliness token gone): emergency stop sent" in err
    assert "lost robot 1 after step" in out and "over the 3 robots that finished" in out
    result = json.loads(run.result_file.read_text())
    assert [r["robot"] for r in result["lost"]] == [1]
    assert result["steps"][-1]["ids"] == [0, 2, 3]
    msgs = _recorded(run)
    event = next(i for i, m in enumerate(msgs) if type(m).__name__ == "RobotEvent")
    assert (msgs[event].robot, msgs[event].kind) == (1, "lost")
    stops = [m for m in msgs if type(m).__name__ == "EmergencyStop"]
    assert [list(m.robots) for m in stops] == [[1]]  # only the lost robot was stopped; the run ended normally
    assert not any(isinstance(m, MotionCommand) and m.robot == 1 for m in msgs[event:])  # never commanded again
    info = recording_info(run.recording)
    assert info["complete"] and info["metadata"]["recorder"]["clean_stop"]
    assert all(p.returncode is not None for p in run.children())
    assert _alive_with(run.run_id) == []


def _assert_lost_cleanly(run: Run) -> None:
    """``--on-lost abort``: exit 3 naming the robot, the lost robot's stop and the run-wide stop, a finished recording."""
    err = "".join(run.stderr)
    assert run.coordinator.returncode == 3, f"exit status {run.coordinator.returncode}: {err}"
    assert "lost robot 1 (liveliness token gone); the policy for a lost robot is abort: the run ends" in err
    result = json.loads(run.result_file.read_text())  # what the run completed before it ended is kept
    assert [lost["robot"] for lost in result["lost"]] == [1] and len(result["steps"]) < 8  # ref57 would have made 8 steps
    assert "lost robot 1 after step" in "".join(run.stdout)  # the summary names it
    # the failed run's recording is finished and names its path
    assert f"recorded {run.recording}: " in "".join(run.stdout)
    info = recording_info(run.recording)
    assert info["complete"] and info["metadata"]["recorder"]["clean_stop"] and info["messages"] > 0
    plans = [c["messages"] for c in info["channels"] if c["topic"] == coord_key(run.run_id, "plan")]
    assert plans and 1 <= plans[0] < 8  # ref57: 4 configurations x 2 steps would be 8 plans; it stopped early
    stops = [m for m in _recorded(run) if type(m).__name__ == "EmergencyStop"]
    assert sorted(list(m.robots) for m in stops) == [[], [1]]  # the lost robot at once, and the whole run at the abort
    assert all(p.returncode is not None for p in run.children())
    assert _alive_with(run.run_id) == []


def test_on_lost_abort_ends_the_run_and_stops_every_robot(tmp_path):
    _assert_lost_cleanly(_kill_an_agent_mid_run(tmp_path))


def test_lost_agent_exit_path_twenty_times(tmp_path):
    """The lost-agent exit path (``--on-lost abort``), repeated: the coordinator must exit with status 3 every time.

    It once died with signal 6 ("FATAL: exception not rethrown") right after "robot 1 lost":
    a Zenoh thread entering Python while the interpreter was finalizing (see
    swarm_cli/coordinator_cmd.py, ``__main__``).
    """
    for k in range(20):
        (tmp_path / f"run{k}").mkdir()
        run = _kill_an_agent_mid_run(tmp_path / f"run{k}")
        assert run.coordinator.returncode != -signal.SIGABRT, f"run {k}: coordinator aborted: {''.join(run.stderr)}"
        _assert_lost_cleanly(run)


def _garbage(run: Run) -> list[tuple[str, bytes]]:
    """Malformed, truncated and wrong-typed messages on every key of the run."""
    r, robots = run.run_id, [int(i) for i in run.traj.ids]
    big = 10**6  # steps the run never reaches: a refusal of these must not disturb it
    good = [
        encode(MotionCommand(run=r, step=big, robot=0, config=1, turn_rad=0.1, drive_m=0.1)),
        encode(ObservationReport(run=r, step=big, robot=0, observed=[1], ranges=[0.2], bearings=[0.1])),
        encode(TruthMessage(run=r, step=big, robot=0, pose=[0.0, 0.0, 0.0])),
        encode(Status(run=r, step=big, robot=0, state="done", reason="")),
    ]
    payloads = [b"", b"\xc1", b"\x93\x01", msgpack.packb([1, 2, 3]), msgpack.packb("hello"), *[g[: len(g) // 2] for g in good]]
    payloads += [
        msgpack.packb({"type": "MotionCommand", "v": 1, "run": r, "step": big, "stamp_ns": 1, "robot": 0, "config": 1,
                       "turn_rad": "left", "drive_m": 0.1}),
        msgpack.packb({"type": "ObservationReport", "v": 1, "run": r, "step": "1", "stamp_ns": 1, "robot": 0,
                       "observed": [1], "ranges": [float("nan")], "bearings": [0.0]}),
        msgpack.packb({"type": "TruthMessage", "v": 2, "run": r, "step": 1, "stamp_ns": 1, "robot": 0, "pose": [0, 0, 0]}),
        msgpack.packb({"type": "Status", "v": 1, "run": r, "step": True, "stamp_ns": 1, "robot": 0, "state": "done", "reason": ""}),
        *good,  # valid messages, but on the wrong keys for most of them
    ]
    keys = [coord_key(r, "plan"), coord_key(r, "estimate"), truths_key(r)]
    for robot in robots:
        keys += [robot_key(r, robot, leaf) for leaf in ("cmd", "observe", "status", "obs")] + [truth_key(r, robot)]
    own = {message_key(decode(g)): g for g in good}  # a valid message on its own key is not garbage
    return [(k, p) for k in keys for p in payloads if own.get(k) != p]


def test_bad_messages_do_not_disturb_a_run(tmp_path):
    seed = 4
    traj = random_trajectory(3, 2, np.random.default_rng(seed))
    run = Run(tmp_path, traj, "no-anchors", seed, motion_time=0.05)
    stop = threading.Event()
    try:
        run.start()
        run.wait_stderr("agents alive", 30)
        garbage = _garbage(run)
        fuzz = open_session(run.member)

        def spam() -> None:
            while not stop.is_set():
                for key, payload in garbage:
                    publish(fuzz, key, payload)
                time.sleep(0.05)

        spammer = threading.Thread(target=spam, daemon=True)
        spammer.start()
        try:
            run.finish(60)
        finally:
            stop.set()
            spammer.join(timeout=5)
            fuzz.close()
        assert run.coordinator.returncode == 0, "".join(run.stderr)
        assert all(p.poll() is None for p in run.agents.values()), "an agent died"
        assert "dropped message" in "".join(run.stderr)
        _assert_same_as_in_process(run)  # the garbage changed nothing
    finally:
        stop.set()
        run.stop()
    assert all(p.returncode is not None for p in run.children())
    assert _alive_with(run.run_id) == []


def test_the_api_distributed_run_equals_the_in_process_one(tmp_path):
    """``inchworm.run_distributed``: agent processes over a loopback hub, the coordinator in this process (its
    recording named by a plain ``str``)."""
    import inchworm

    run = inchworm.simulate(robots=4, configs=2, seed=5, method="ref57")
    distributed = inchworm.run_distributed(run.trajectory, method="ref57", seed=5, record=str(tmp_path / "api.mcap"))
    assert (tmp_path / "api.mcap").stat().st_size > 0
    assert distributed.pf() == run.pf()
    assert all(np.array_equal(a.estimate.poses, b.estimate.poses) for a, b in zip(run.steps, distributed.steps, strict=True))



def test_a_distributed_run_as_an_object_with_a_lifecycle():
    """``inchworm.DistributedRun``: its agents' liveliness in ``status()``, the run-wide stop acknowledged by every agent,
    the stopped run a ``SwarmRunError`` and status 3, every agent process ended when the block is left."""
    import inchworm

    with inchworm.DistributedRun(robots=4, configs=2, seed=5, method="ref57") as run:
        assert run.status().state == "running" and run.status().hub == run.hub
        wait_for(lambda: run.status().agents == (0, 1, 2, 3), 30.0, "the four agents' liveliness")
        assert sorted(run.estop("a test").agents) == [0, 1, 2, 3]
        with pytest.raises(inchworm.SwarmRunError, match="the run was stopped by inchworm.DistributedRun .* \\(a test\\)"):
            run.wait()
        assert run.status().state == "ended" and run.status().status == 3
        with pytest.raises(inchworm.SwarmInputError, match="has no result"):
            run.result()
    assert run._procs and all(p.poll() is not None for p in run._procs)
