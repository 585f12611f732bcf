"""Coordination overhead of the distributed runtime per step (``swarm bench runtime``).

For each swarm size N (``agents``, e.g. 10 and 50) the benchmark starts, on this host, a Zenoh
router hub in its own process and the agents of N robots (as ``swarm launch`` does,
simulated drivers, no motion delay: one process per robot up to 50 robots, else processes
hosting up to 50 agents each; ``agents_per_process`` to choose), then runs the coordinator in process: a
``ZenohSwarmBackend`` (a client of the hub, like ``swarm coordinator``) under the same
``InchwormExecutor``, with a fixed plan (``method`` ``no-anchors``: everybody moves every
step, or ``ref57``) along a random trajectory, for ``steps`` steps (with bodies, the model's
``robot_radius_m`` > 0, the plan's moves are split into collision-free groups: at 500 robots one or
two move per step; radius 0 keeps everybody moving). A step's time runs
from the end of the previous step (or of the plan) to the published fused estimate:
commands out, every ``Status done`` back, observation requests out, every report (and
simulated truth) back, localization, ``EstimateMessage`` published. No simulated motion
time is included (motion time 0). Reported per N:

* ``step_ms_median``: median step time (ms);
* ``zenoh_rtt_ms``: the raw Zenoh round trip between two client sessions through the
  same hub (``runtime.wire.transport.round_trip_ms``, median), measured in the same run with
  the agents alive, and the step time as a multiple of it;
* beside them (table only): the median of the command round (``execute``: commands out,
  every ``done`` back) and of the observation round (``observe``: requests out, every
  report and truth back); the rest of a step is localization and publishing;
* ``breakdown_ms``: where a step's time goes (medians over the steps, ms): ``commands``
  (commands out, every ``done`` back), ``observe`` (observation requests out, every report and
  truth back), ``localize`` (the rest of the step before the estimate goes out: localization
  and the executor's bookkeeping) and ``publish_estimate`` (the ``EstimateMessage``);
* ``cpu_ms_per_step``: CPU time (user + system, ms) per timed step of the ``agents`` (every
  process the benchmark started: agent processes, and with the gateway driver the link
  processes and the emulator) and of the ``coordinator`` (this process: the coordinator, its
  Zenoh session and the hub). Above the wall time of a step times the cores, the step is
  waiting for a core;
* ``agents_per_process``: robot agents hosted by one agent process;
* ``agent_rss_mb``: resident memory per robot agent after the run: the agent processes'
  ``VmRSS`` (``/proc/<pid>/status``, MB = 2^20 bytes) summed and divided by the N agents they host.

Every process started is stopped by its own pid at the end, on error and on Ctrl-C.
Targets: N = 10 under 20 ms, N = 50 under 100 ms per step, agents under 80 MB;
N = 200 under 400 ms, N = 500 under 1 s, under 15 MB per agent.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec
import numpy as np

from inchworm.bench import BenchResult
from inchworm.bench.options import RuntimeBenchOptions
from runtime.errors import OptionError, SwarmRunError
from runtime.models.trajectory import body_spacing, random_trajectory

if TYPE_CHECKING:
    from coordinator.backend import SwarmBackend
    from coordinator.executor import ExecutorListener
    from coordinator.legs import LegRecord
    from coordinator.plan import Plan
    from coordinator.run_result import ContactEvent
    from coordinator.selection.selector import Selection
    from runtime.models.state import Observations, StepCommands, SwarmEstimate

METHODS = ("no-anchors", "ref57")


class EnoughSteps(Exception):
    """Raised by ``StepTimer`` once it timed ``limit`` steps: ends the run there (not an error)."""


class StepTimer:
    """``ExecutorListener`` that forwards to ``inner`` and times each step up to its published estimate; after
    ``limit`` steps it raises ``EnoughSteps`` (with bodies, ``clear_plan`` splits a configuration's moves into as
    many steps as it needs to keep them apart: hundreds at 500 robots, so the configurations alone do not bound
    the run)."""

    def __init__(self, inner: ExecutorListener, limit: int | None = None) -> None:
        self.inner = inner
        self.limit = limit
        self.mark: float | None = None
        self.seconds: list[float] = []
        self.publish_s: list[float] = []  # the inner on_estimate of each timed step (publishing the estimate)

    def on_plan(self, config_index: int, first_step: int, plan: Plan, selection: Selection | None) -> None:
        self.inner.on_plan(config_index, first_step, plan, selection)
        self.mark = time.perf_counter()

    def on_leg(self, config_index: int, leg: int, first_step: int, record: LegRecord) -> None:
        on_leg = getattr(self.inner, "on_leg", None)
        if on_leg is not None:
            on_leg(config_index, leg, first_step, record)
        self.mark = time.perf_counter()

    def on_contacts(self, contacts: list[ContactEvent]) -> None:
        self.inner.on_contacts(contacts)

    def on_estimate(self, step: int, estimate: SwarmEstimate) -> None:
        start = time.perf_counter()
        self.inner.on_estimate(step, estimate)
        now = time.perf_counter()
        if step > 0 and self.mark is not None:
            self.seconds.append(now - self.mark)
            self.publish_s.append(now - start)
        self.mark = now
        if self.limit is not None and len(self.seconds) >= self.limit:
            raise EnoughSteps


class TimedBackend:
    """The backend with its ``execute`` and ``observe`` calls timed (seconds)."""

    def __init__(self, inner: SwarmBackend) -> None:
        self.inner, self.ids = inner, inner.ids
        self.execute_s: list[float] = []
        self.observe_s: list[float] = []

    def execute(self, step: StepCommands) -> None:
        t = time.perf_counter()
        self.inner.execute(step)
        self.execute_s.append(time.perf_counter() - t)

    def observe(self) -> Observations:
        t = time.perf_counter()
        obs = self.inner.observe()
        self.observe_s.append(time.perf_counter() - t)
        return obs

    def true_poses(self) -> np.ndarray | None:
        return self.inner.true_poses()

    def take_lost(self) -> dict[int, str]:
        lost = self.inner.take_lost()
        self.ids = self.inner.ids
        return lost


def rss_mb(pid: int) -> float | None:
    """Resident set size of process ``pid`` in MB (VmRSS), or None if it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of process ``pid`` so far (s; its threads included), 0 if it is gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def breakdown(timer: StepTimer, timed: TimedBackend) -> dict[str, float]:
    """Medians (ms) of a step's parts: the command round, the observation round, the rest up to the estimate
    (localization, bookkeeping) and publishing the estimate (``timer`` and ``timed`` time the same steps)."""
    parts = list(zip(timer.seconds, timed.execute_s[-len(timer.seconds):], timed.observe_s[-len(timer.seconds):],
                     timer.publish_s, strict=True))

    def med(values: list[float]) -> float:
        return round(statistics.median(values) * 1e3, 3)

    return {"commands": med([c for _, c, _, _ in parts]), "observe": med([o for _, _, o, _ in parts]),
            "localize": med([s - c - o - p for s, c, o, p in parts]), "publish_estimate": med([p for _, _, _, p in parts])}


def _say(text: str) -> None:
    print(f"bench runtime: {text}", file=sys.stderr, flush=True)


def _raise_interrupt(*_: object) -> None:
    raise KeyboardInterrupt


def measure(n: int, args: RuntimeBenchOptions, driver: str = "sim") -> dict[str, Any]:
    """Start the hub and ``n`` agents, time ``args.steps`` steps, stop everything; one result row.

    ``driver="gateway"``: the agents drive emulated robots through their links and ptys
    (``inchworm.processes.start_gateway``, default gateway config), as ``swarm demo --driver gateway``: without
    ``agents_per_process``, one process per port runs its link and its robots' agents (``start_port_hosts``), with it,
    link processes apart.
    """
    from coordinator.executor import InchwormExecutor  # noqa: PLC0415
    from coordinator.localization import make_localizer  # noqa: PLC0415
    from coordinator.node.zenoh_backend import AgentError, Timeouts, ZenohSwarmBackend  # noqa: PLC0415
    from coordinator.selection.selector import SelectionConfig  # noqa: PLC0415
    from coordinator.simulate import initial_estimate  # noqa: PLC0415
    from coordinator.strategies import FixedPlanStrategy, make_strategy  # noqa: PLC0415
    from inchworm.processes import agents_per_process, default_gateway, start_agents, start_gateway, start_port_hosts, stop_all  # noqa: PLC0415
    from inchworm.specs import AgentHostSpec, EmulatorSpec  # noqa: PLC0415
    from runtime.wire.transport import free_tcp_port, loopback_hub, open_session, round_trip_ms  # noqa: PLC0415
    cfg = args.model
    strategy = make_strategy(args.method, n, cfg, make_localizer(args.localizer, cfg), SelectionConfig(), args.seed)
    assert isinstance(strategy, FixedPlanStrategy)  # --method: a fixed plan
    per_config = strategy.fixed.n_steps
    configs = math.ceil(args.steps / per_config)
    traj = random_trajectory(n, configs, np.random.default_rng([args.seed, n]), sensing_range=cfg.sensing_range_m, **body_spacing(cfg))
    per_process = agents_per_process(n, args.agents_per_process)
    gateway = default_gateway(traj, robot_radius=cfg.robot_radius_m) if driver == "gateway" else None
    port_hosts = gateway is not None and args.agents_per_process is None
    if gateway is not None and port_hosts:
        per_process = max(len(p.robots) for p in gateway.ports)
    run_id = f"bench-runtime-{os.getpid()}-{n}-{driver}"
    port = free_tcp_port()
    hub_settings, member = loopback_hub(port)
    hub = f"tcp/127.0.0.1:{port}"
    procs: list[subprocess.Popen[Any]] = []
    try:
        with open_session(hub_settings), tempfile.TemporaryDirectory(prefix="swarm-bench-") as tmp:
            t0 = time.monotonic()
            _say(f"{n} agents ({driver} driver, {per_process} per process): starting (run {run_id}, hub {hub})")
            agent = AgentHostSpec(run_id=run_id, robots=(), hub=hub, seed=args.seed, model=cfg)
            traj_file = Path(tmp) / "trajectory.json"
            traj.save(traj_file)
            if gateway is not None:
                emulator = EmulatorSpec(config="", trajectory=str(traj_file), seed=args.seed, model=cfg, hub=hub, run_id=run_id)
                live = start_gateway(gateway, Path(tmp), emulator, procs, links=not port_hosts)
                agent = msgspec.structs.replace(agent, driver="gateway", gateway_config=str(live))
            first_agent = len(procs)
            if port_hosts:
                hosts = start_port_hosts(traj, live, agent, procs, traj_file, stdout=subprocess.DEVNULL)
            else:
                start_agents(traj, agent, procs, per_process, traj_file, stdout=subprocess.DEVNULL)
                hosts = {int(r): procs[first_agent + k // per_process] for k, r in enumerate(traj.ids)}
            with open_session(member) as session:
                backend = ZenohSwarmBackend(session, run_id, traj.ids.tolist(), Timeouts(args.start_timeout_s, args.step_timeout_s),
                                            robot_radius_m=cfg.robot_radius_m)
                try:
                    backend.wait_for_agents()
                    _say(f"{n} agents: all alive after {time.monotonic() - t0:.1f} s; raw Zenoh round trip ...")
                    rtt = round_trip_ms(member, member, args.rtt_count)["median_ms"]
                    _say(f"{n} agents: round trip {rtt:.3f} ms; timing {configs * per_config} steps ({args.method})")
                    timer = StepTimer(backend, configs * per_config)
                    progress = lambda done, total: _say(f"{n} agents: configuration {done}/{total} (step {backend.step})")  # noqa: E731
                    timed = TimedBackend(backend)
                    executor = InchwormExecutor(timed, make_localizer(args.localizer, cfg), strategy, cfg, progress, listener=timer)
                    cpu_before = (sum(cpu_seconds(p.pid) for p in procs), cpu_seconds(os.getpid()))
                    with contextlib.suppress(EnoughSteps):
                        executor.run(traj, initial_estimate(traj, args.seed, 0.01, math.radians(2.0)))
                    cpu_after = (sum(cpu_seconds(p.pid) for p in procs), cpu_seconds(os.getpid()))
                finally:
                    backend.close()
            rss = [rss_mb(p.pid) for p in procs[first_agent:]]
            dead = sorted(r for r, p in hosts.items() if p.poll() is not None)
            if dead or None in rss:
                raise AgentError(f"agent processes of robots {dead} exited during the benchmark", dead)
    finally:
        emulators = 1 if driver == "gateway" else 0  # stopped last, after the links that read their ptys
        stop_all(procs[emulators:])
        stop_all(procs[:emulators])
    left = [p.pid for p in procs if p.poll() is None]
    if left:
        raise SwarmRunError(f"agent processes {left} are still running")
    step_ms = [s * 1e3 for s in timer.seconds]
    steps = len(timed.execute_s)  # every step run (CPU includes the planning between configurations)
    cpu = {"agents": round((cpu_after[0] - cpu_before[0]) * 1e3 / steps, 3), "coordinator": round((cpu_after[1] - cpu_before[1]) * 1e3 / steps, 3)}
    return {"agents": n, "step_ms_median": round(statistics.median(step_ms), 3), "zenoh_rtt_ms": round(rtt, 4),
            "agent_rss_mb": round(sum(r or 0.0 for r in rss) / n, 2), "agents_per_process": per_process,
            "breakdown_ms": breakdown(timer, timed), "cpu_ms_per_step": cpu,
            "_steps": len(step_ms), "_step_ms": step_ms, "_step_ms_p90": _p90(step_ms)}


def _p90(values: list[float]) -> float:
    return round(statistics.quantiles(values, n=10)[-1], 3) if len(values) >= 2 else round(values[0], 3)


def bench_runtime(options: RuntimeBenchOptions | None = None) -> BenchResult:
    """Time the steps of a distributed run per swarm size (``options`` None: the defaults); ``AgentError`` if agents
    did not come up or died."""
    from coordinator.node.zenoh_backend import AgentError  # noqa: PLC0415

    args = options or RuntimeBenchOptions()
    sizes = list(args.agents)
    if not sizes or min(sizes) < 2:
        raise OptionError("agents", f"must list integers >= 2, got {args.agents}", args)
    if args.steps < 1:
        raise OptionError("steps", f"must be >= 1, got {args.steps}", args)
    if args.rtt_count < 2:
        raise OptionError("rtt_count", f"must be >= 2, got {args.rtt_count}", args)
    if args.method == "ref57" and any(n % 2 for n in sizes):
        raise OptionError("method", "ref57 needs even numbers of agents", args)
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    rows = []
    try:
        for n in sizes:
            try:
                rows.append(measure(n, args))
            except AgentError as exc:
                raise AgentError(f"{n} agents: {exc}", exc.robots) from exc
    finally:
        signal.signal(signal.SIGTERM, previous)
    lines = [f"{'agents':>6} {'per proc':>8} {'steps':>5} {'step ms (median)':>16} {'p90':>7} {'zenoh rtt ms':>12} "
             f"{'step / rtt':>10} {'commands ms':>11} {'observe ms':>10} {'localize ms':>11} {'estimate ms':>11} "
             f"{'CPU ms agents':>13} {'CPU ms coord':>12} {'RSS MB per agent':>16}"]
    for r in rows:
        b, c = r["breakdown_ms"], r["cpu_ms_per_step"]
        lines.append(f"{r['agents']:>6} {r['agents_per_process']:>8} {r['_steps']:>5} {r['step_ms_median']:>16.2f} "
              f"{r['_step_ms_p90']:>7.2f} {r['zenoh_rtt_ms']:>12.3f} "
              f"{r['step_ms_median'] / r['zenoh_rtt_ms']:>10.0f} {b['commands']:>11.2f} {b['observe']:>10.2f} {b['localize']:>11.2f} "
              f"{b['publish_estimate']:>11.2f} {c['agents']:>13.2f} {c['coordinator']:>12.2f} {r['agent_rss_mb']:>16.2f}")
    from coordinator.localization.sparse_lm import sparse_backend  # noqa: PLC0415
    lines.append(f"sparse factorization of the localizers: {sparse_backend()}")
    summary = {"results": [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]}
    return BenchResult(rows, summary, "\n".join(lines), "agents", "step_ms_median", "step time, median (ms)",
                       f"Coordination time per step ({args.method}, {args.localizer} localizer)")
