"""The run survives the faults of real swarms (``swarm bench faults``; docs/failure-model.md).

Three parts, each through the options a user has, with real processes on loopback:

* ``lost_robot``: ``swarm launch -n 10 --kill-robot 3@2 --json`` per seed; a run is
  completed when it exits 0 with every configuration done by the other robots;
  ``detect_ms`` is the kill -> the coordinator's targeted ``EmergencyStop`` (its stamp),
  ``estop_ms`` the kill -> that stop heard by a subscriber (the launcher).
* ``fuzz``: a distributed run (hub, agents, coordinator) while another client publishes
  ``fuzz`` hostile messages on every key of the run: random bytes, wrong types,
  NaN / inf / huge values, future steps, unknown robot ids and replays of the run's own
  earlier messages. ``process_deaths`` counts agents or coordinator that died; ``identical``:
  the per-configuration table and P_f equal the in-process run of the same seed (which the
  distributed run reproduces bit for bit without faults).
* ``coordinator``: ``swarm launch -n 10 --standby --kill-coordinator STEP --json`` per seed, STEP
  drawn at random among the run's steps (seeded): the coordinator is SIGKILLed, the standby takes
  the run over from its last checkpoint; ``completed`` counts runs that exit 0 with every
  configuration done, ``identical`` those whose per-configuration table and P_f equal the
  in-process run of the same seed, ``takeover_ms_max`` the longest kill -> first command of the
  new coordinator. ``coordinator_joint``: the same with ``--localizer joint``, whose estimate carries its joint
  covariance from step to step (in the checkpoint too), against the in-process run with that localizer.
* ``gateway``: radio faults injected by the robot emulators
  (``swarm launch --driver gateway --drop --corrupt --delay``), see
  ``inchworm.bench.faults_gateway``.
* ``estop_under_flood``: emergency stops through the deploy/ TLS router's operator listener (mutual
  TLS, access control, the estop identity), one a second while ``flood`` idle TCP connections are held
  on its public listener for ``flood_s`` seconds and for ``min(flood_s, 60)`` s after, see
  ``inchworm.bench.estop_flood``.
* ``forged_link_requests``: a gateway run (link processes apart) while a client allowed on ``linkreq``
  forges requests for every command, and after the coordinator exited; ``executed`` counts the motions
  no coordinator asked for (must be 0), see ``inchworm.bench.forged_links``.

``to_json()`` (``swarm bench faults --json``): ``{"gateway": [...], "lost_robot": {...}, "fuzz": {...},
"coordinator": {"runs", "completed", "identical", "takeover_ms_max"},
"estop_under_flood": {"connections", "tls", "robots", "reached", "ms_max", "duration_s", "after_s", "stops", "late", "probes",
"public_blocked"}, "coordinator_joint": {as "coordinator"},
"forged_link_requests": {"sent", "executed", "completed"}, "rejoin": {"runs", "rejoined", "sensing_range_m"},
"coordinator_stall": {"stall_s", "runs", "completed"}}`` (``inchworm.bench.faults_stalls``).
"""

from __future__ import annotations

import json
import math
import statistics
import subprocess
import tempfile
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgpack
import numpy as np

from inchworm.bench import BenchResult
from inchworm.bench.options import FaultsBenchOptions
from inchworm.output import last_json
from inchworm.progress import Progress
from inchworm.spawn import Spawned, run_process
from inchworm.specs import AgentHostSpec, CoordinatorSpec, LaunchSpec
from runtime.errors import OptionError
from runtime.models.config import ModelConfig
from runtime.models.trajectory import body_spacing, random_trajectory
from runtime.wire.keys import coord_key, estop_key, robot_key, robot_wildcard, run_wildcard, truth_key, truths_key
from runtime.wire.messages import MotionCommand, ObservationReport, ObserveRequest, Status, TruthMessage, TruthSetMessage, encode

if TYPE_CHECKING:
    from coordinator.run_result import RunResult


# -- lost robot ------------------------------------------------------------------------------


def lost_robot(seeds: int, robots: int = 10, configs: int = 3, victim: int = 3, step: int = 2) -> dict[str, Any]:
    """``swarm launch --kill-robot victim@step`` for seeds 0..seeds-1: detection and stop times, completion;
    ``summaries`` holds each run's JSON (the coordinator's, with the launcher's ``"kill"``) and ``"returncode"``."""
    summaries = []
    progress = Progress(seeds, "lost robot")
    for seed in range(seeds):
        with tempfile.TemporaryDirectory(prefix="bench-faults-") as tmp:
            proc = run_process(LaunchSpec(robots=robots, configs=configs, trajectory_seed=seed, seed=seed, kill_robot=((victim, step),),
                                          motion_time=0.1, no_record=True, out=tmp, json=True), timeout=600, cwd=tmp)
        summaries.append({**(last_json(proc.stdout) or {}), "returncode": proc.returncode})
        progress(seed + 1)
    done = [s for s in summaries
            if s["returncode"] == 0 and len(s.get("configs", [])) == configs and s.get("finished_robots") == robots - 1]
    kills = [s["kill"] for s in summaries if s.get("kill") and s["kill"].get("detect_ms") is not None]
    return {"detect_ms_median": statistics.median(k["detect_ms"] for k in kills) if kills else None,
            "completed": len(done) == seeds, "estop_ms_max": max(k["estop_ms"] for k in kills) if kills else None,
            "runs": seeds, "runs_completed": len(done), "summaries": summaries}


# -- coordinator killed, standby taking over -----------------------------------------------------


def coordinator_takeover(seeds: int, robots: int = 10, configs: int = 3, localizer: str = "paper") -> dict[str, Any]:
    """``swarm launch --localizer LOCALIZER --standby --kill-coordinator STEP`` for seeds 0..seeds-1, STEP drawn among
    the run's steps; each run compared with the in-process run of its seed. ``summaries``: each run's JSON and
    ``"returncode"``."""
    from coordinator.simulate import simulate  # noqa: PLC0415

    summaries, identical = [], 0
    progress = Progress(seeds, f"coordinator ({localizer} localizer)")
    for seed in range(seeds):
        traj = random_trajectory(robots, configs, np.random.default_rng(seed), **body_spacing(ModelConfig()))  # as launch draws it
        ref = simulate(traj, "inchworm", ModelConfig(), localizer=localizer, seed=seed)
        step = int(np.random.default_rng([seed, 41]).integers(1, len(ref.steps) + 1))
        with tempfile.TemporaryDirectory(prefix="bench-faults-") as tmp:
            proc = run_process(LaunchSpec(robots=robots, configs=configs, trajectory_seed=seed, seed=seed, localizer=localizer, standby=True,
                                          kill_coordinator=step, motion_time=0.1, no_record=True, out=tmp, json=True), timeout=600, cwd=tmp)
        summary = {**(last_json(proc.stdout) or {}), "returncode": proc.returncode}
        summaries.append(summary)
        identical += summary["returncode"] == 0 and same_table(summary, ref)
        progress(seed + 1)
    done = [s for s in summaries if s["returncode"] == 0 and len(s.get("configs", [])) == configs]
    takeovers = [s["coordinator_kill"]["takeover_ms"] for s in summaries if s.get("coordinator_kill")]
    return {"runs": seeds, "completed": len(done), "identical": identical,
            "takeover_ms_max": None if not takeovers or None in takeovers else max(takeovers), "summaries": summaries}


# -- hostile messages ---------------------------------------------------------------------------


class Fuzzer:
    """Hostile payloads for run ``run_id`` with robots ``robots``, drawn from ``rng``; ``heard`` feeds the replays."""

    def __init__(self, run_id: str, robots: list[int], rng: np.random.Generator) -> None:
        self.run_id, self.robots, self.rng = run_id, robots, rng
        self.heard: list[tuple[str, bytes]] = []
        self.kinds = list(range(6))  # 0 random bytes, 1 wrong types and future steps, 2 bad values, 3 unknown ids, 4 versions, 5 replays
        r = run_id
        self.keys = [coord_key(r, "plan"), coord_key(r, "estimate"), coord_key(r, "event"), truths_key(r), estop_key(r),
                     f"swarm/{r}/link/radio0/stats", robot_key(r, 10**6, "cmd"), robot_key(r, 10**6, "status")]
        for robot in robots:
            self.keys += [robot_key(r, robot, leaf) for leaf in ("cmd", "observe", "status", "obs")] + [truth_key(r, robot)]

    def on_heard(self, key: str, payload: bytes) -> None:
        if len(self.heard) < 5000:
            self.heard.append((key, payload))

    def message(self) -> tuple[str, bytes]:
        """One hostile (key, payload); never a valid emergency stop (that is a real stop, not a fault)."""
        key = self.keys[int(self.rng.integers(len(self.keys)))]
        kind = int(self.rng.choice(self.kinds))
        if kind == 5 and self.heard:  # a replay of an earlier message of the run, on its own key
            return self.heard[int(self.rng.integers(len(self.heard)))]
        if kind == 0 or key == estop_key(self.run_id):
            return key, self.rng.bytes(int(self.rng.integers(0, 64)))
        robot = self.robots[int(self.rng.integers(len(self.robots)))]
        far = int(self.rng.integers(10**3, 10**9))  # a step the run never reaches
        r = self.run_id
        if kind == 1:  # valid messages of the wrong type for the key, and future steps
            msg = [MotionCommand(run=r, step=far, robot=robot, config=1, turn_rad=0.1, drive_m=0.1, cmd_id=far),
                   ObserveRequest(run=r, step=far, robot=robot),
                   Status(run=r, step=far, robot=robot, state="refused", reason="fuzz", cmd_id=far),
                   ObservationReport(run=r, step=far, robot=robot, observed=(), ranges=(), bearings=()),
                   TruthMessage(run=r, step=far, robot=robot, pose=(9.0, 9.0, 0.0)),
                   TruthSetMessage(run=r, step=far, ids=(robot,), poses=((9.0, 9.0, 0.0),))][int(self.rng.integers(6))]
            return key, encode(msg)
        bad = [math.nan, math.inf, -math.inf, 1e308, -1e39, 2**64 + 5, -1, "x", None, [1.0]][int(self.rng.integers(10))]
        if kind == 2:  # non-finite, huge, negative or wrong-typed values in an otherwise valid command
            raw = {"type": "MotionCommand", "v": 1, "run": r, "step": far, "stamp_ns": 1, "robot": robot, "config": 1,
                   "turn_rad": bad, "drive_m": 0.1}
        elif kind == 3:  # unknown robot ids
            raw = {"type": "ObservationReport", "v": 1, "run": r, "step": far, "stamp_ns": 1, "robot": robot,
                   "observed": [10**6], "ranges": [0.2], "bearings": [0.1]}
        else:  # an unsupported version, a wrong type in the header
            raw = {"type": "Status", "v": int(self.rng.integers(2, 9)), "run": r, "step": bad, "stamp_ns": 1, "robot": robot,
                   "state": "done", "reason": ""}
        try:
            return key, msgpack.packb(raw)
        except (OverflowError, TypeError, ValueError):
            return key, self.rng.bytes(16)


def fuzz(count: int, seed: int = 7, robots: int = 6, configs: int = 6, method: str = "ref57", rate: float = 4000.0) -> dict[str, Any]:
    """A distributed run under ``count`` hostile messages (``rate`` per second, from its first command on);
    compared with the in-process run of the same seed."""
    from coordinator.simulate import simulate  # noqa: PLC0415
    from inchworm.processes import start_agents, stop_all  # noqa: PLC0415
    from runtime.wire.transport import free_tcp_port, loopback_hub, open_session, publish, subscribe  # noqa: PLC0415
    traj = random_trajectory(robots, configs, np.random.default_rng(seed), **body_spacing(ModelConfig()))
    run_id = f"fuzz{uuid.uuid4().hex[:8]}"
    port = free_tcp_port()
    hub_settings, member = loopback_hub(port)
    hub = f"tcp/127.0.0.1:{port}"
    procs: list[subprocess.Popen[Any]] = []
    sent = 0
    with tempfile.TemporaryDirectory(prefix="bench-fuzz-") as tmp, open_session(hub_settings) as hub_session:
        traj_file = Path(tmp) / "traj.json"
        traj.save(traj_file)
        fuzzer = Fuzzer(run_id, [int(i) for i in traj.ids], np.random.default_rng([seed, 99]))
        started = threading.Event()
        listener = subscribe(hub_session, run_wildcard(run_id), fuzzer.on_heard)
        watcher = subscribe(hub_session, robot_wildcard(run_id, "cmd"), lambda *_: started.set())
        try:
            agents = list(start_agents(traj, AgentHostSpec(run_id=run_id, robots=(), hub=hub, seed=seed, motion_time=0.3), procs,
                                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            coordinator = Spawned(CoordinatorSpec(trajectory=str(traj_file), method=method, run_id=run_id, hub=hub, seed=seed, no_record=True,
                                                  json=True), stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
            procs.append(coordinator)
            started.wait(timeout=60)
            progress = Progress(count, "fuzz")
            with open_session(member) as attacker:
                while sent < count and coordinator.poll() is None:
                    key, payload = fuzzer.message()
                    publish(attacker, key, payload)
                    sent += 1
                    if sent % 100 == 0:
                        progress(sent)
                        time.sleep(100 / rate)  # a hostile client, not a flood of the machine
            out, _ = coordinator.communicate(timeout=300)
            deaths = sum(1 for p in agents if p.poll() is not None) + (coordinator.returncode != 0)
        finally:
            listener.undeclare()
            watcher.undeclare()
            stop_all(procs)
        summary = last_json(out) or {}
    ref = simulate(traj, method, ModelConfig(), seed=seed)
    identical = bool(summary) and same_table(summary, ref)
    return {"sent": sent, "process_deaths": deaths, "completed": coordinator.returncode == 0, "identical": identical}


def same_table(summary: dict[str, Any], ref: RunResult) -> bool:
    """The coordinator's per-configuration rows and P_f equal the in-process run's (to 1e-12: the distributed
    run reproduces every estimate bit for bit; the table's sums may differ in the last bit); a row's ``steps`` are
    the configuration's steps taken, its approach legs' included (``ConfigRecord.n_steps``)."""
    e_l, follow, travelled = ref.localization_errors(), ref.following_errors(), ref.travelled()
    rows = summary.get("configs", [])

    def same(a: float | None, b: float) -> bool:  # to 1e-12: summation order
        return a is not None and math.isclose(a, float(b), rel_tol=1e-12, abs_tol=1e-15)

    if len(rows) != len(ref.configs) or not same(summary.get("pf"), ref.pf()):
        return False
    anchors = ref.anchor_counts()
    return all(row["n_a"] == anchors[k] and row["steps"] == c.n_steps and same(row["e_l"], e_l[k])
               and same(row["following_error"], follow[k]) and same(row["travelled"], travelled[k])
               for k, (row, c) in enumerate(zip(rows, ref.configs, strict=True)))


# -- the command ----------------------------------------------------------------------------------


def bench_faults(options: FaultsBenchOptions | None = None, say: Callable[[str], None] | None = None) -> BenchResult:
    """The gateway rows, the lost robot, the fuzz run, the coordinator takeover and the stop under a connection flood;
    ``say`` is told each part's result as it ends (``options`` None: the defaults)."""
    from inchworm.bench.estop_flood import estop_under_flood  # noqa: PLC0415
    from inchworm.bench.faults_gateway import gateway_fault_rows  # noqa: PLC0415
    from inchworm.bench.faults_stalls import coordinator_stall, rejoin  # noqa: PLC0415
    from inchworm.bench.forged_links import forged_link_requests  # noqa: PLC0415

    o = options or FaultsBenchOptions()
    _say = say or (lambda _text: None)
    for name, low in (("seeds", 1), ("fuzz", 0), ("flood", 1)):
        if getattr(o, name) < low:
            raise OptionError(name, f"must be >= {low}, got {getattr(o, name)}", o)
    if not 1.0 <= o.flood_s <= 3600.0:
        raise OptionError("flood_s", f"must be between 1 and 3600, got {o.flood_s:g}", o)
    _say(f"gateway: {len(o.gateway_rows)} radio-fault rows over {o.seeds} seeds (each against its fault-free run)")
    rows = gateway_fault_rows(o.gateway_rows, range(o.seeds)) if o.gateway_rows else []
    for row in rows:
        _say(json.dumps(row))
    _say(f"lost robot: swarm launch -n 10 --kill-robot 3@2 over {o.seeds} seeds")
    lost = lost_robot(o.seeds)
    _say(json.dumps({k: v for k, v in lost.items() if k != "summaries"}))
    _say(f"fuzz: {o.fuzz} hostile messages during a run")
    fz = fuzz(o.fuzz)
    _say(json.dumps(fz))
    _say(f"coordinator: swarm launch -n 10 --standby --kill-coordinator STEP (random) over {o.seeds} seeds")
    coord = {k: v for k, v in coordinator_takeover(o.seeds).items() if k != "summaries"}
    _say(json.dumps(coord))
    _say(f"coordinator, joint localizer: swarm launch -n 10 --localizer joint --standby --kill-coordinator STEP over {o.seeds} seeds")
    coord_joint = {k: v for k, v in coordinator_takeover(o.seeds, localizer="joint").items() if k != "summaries"}
    _say(json.dumps(coord_joint))
    _say(f"estop under flood: {o.flood} idle TCP connections held on the TLS router's public listener for {o.flood_s:g} s, "
         f"a stop a second through its operator listener during the flood and {min(o.flood_s, 60.0):g} s after it")
    flood = estop_under_flood(connections=o.flood, duration_s=o.flood_s, say=_say)
    _say(json.dumps(flood))
    _say("forged link requests: a gateway run (links apart) while the gateway identity forges LinkRequests, and after it")
    forged = forged_link_requests()
    _say(json.dumps(forged))
    _say(f"rejoin: a robot's agent killed and restarted after the swarm moved on, at 0.5 m, over {o.seeds} seeds")
    back = rejoin(o.seeds)
    _say(json.dumps(back))
    _say(f"coordinator stall: swarm launch -n 10 --standby --stall-coordinator STEP:12 over {o.seeds} seeds")
    stall = coordinator_stall(o.seeds)
    _say(json.dumps(stall))
    summary = {"gateway": rows, "lost_robot": {k: lost[k] for k in ("detect_ms_median", "completed", "estop_ms_max")}, "fuzz": fz,
               "coordinator": coord, "estop_under_flood": flood, "coordinator_joint": coord_joint, "forged_link_requests": forged,
               "rejoin": back, "coordinator_stall": stall}
    table = "\n".join([*(json.dumps(r) for r in rows), json.dumps(summary["lost_robot"]), json.dumps(fz), json.dumps(coord),
                       json.dumps(coord_joint), json.dumps(flood), json.dumps(forged), json.dumps(back), json.dumps(stall)])
    return BenchResult(rows, summary, table, "drop", "completed", "completed runs", "Runs completed under radio faults")
