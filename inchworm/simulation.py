"""One simulated run from Python: ``simulate`` runs ``SimOptions`` (``inchworm.sim_options``) and returns a ``SimResult``
(the run with its options; ``to_json()`` is ``swarm sim --json``'s object), and the per-configuration table of a run."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, overload

from coordinator.run_result import RunResult
from inchworm.sim_options import OnProgress, SimOptions
from runtime.errors import OutputError
from runtime.models.config import ModelConfig
from runtime.models.trajectory import Trajectory
from runtime.paths import StrPath

if TYPE_CHECKING:
    from coordinator.localization import Localizer
    from coordinator.run_result import ConfigRecord, StepRecord
    from coordinator.selection.selector import SelectionConfig
    from coordinator.strategies import Strategy
    from runtime.world.params import PhysicsParams


@dataclass(eq=False)
class SimResult(RunResult):
    """A simulated run (every ``RunResult`` field and method) and the ``SimOptions`` it ran (``options``, its
    trajectory the ``Trajectory`` followed)."""

    options: SimOptions | None = None

    @classmethod
    def of(cls, result: RunResult, options: SimOptions) -> SimResult:
        """``result``, the run of ``options``, with them."""
        return cls(**{f.name: getattr(result, f.name) for f in fields(RunResult)}, options=options)

    def to_json(self, plots: Sequence[str] = ()) -> dict[str, Any]:
        """The object ``swarm sim --json`` prints: ``method``, ``localizer``, ``seed``, ``pf``, ``mc_start`` and
        ``mc_emax`` (the anchor search's), ``configs`` (the rows of ``configs.csv``), ``fallback_steps``, ``plots``
        (the figures written of the run: ``inchworm.plots.write_run_plots``), the bodies' keys
        (``inchworm.simulation.contacts_json``) and the world's (``world_json``)."""
        o = self.options
        if o is None:
            raise ValueError("SimResult.to_json needs the options of the run (SimResult.of(result, options))")
        return {"method": o.method if isinstance(o.method, str) else self.method, "localizer": _name(o.localizer), "seed": o.seed,
                "pf": self.pf(), "mc_start": o.selection.mc_start, "mc_emax": o.selection.mc_emax, "configs": config_rows(self),
                "fallback_steps": len(fallback_steps(self)), "plots": list(plots),
                **contacts_json(self, o.model.robot_radius_m), **world_json(self, o.world)}


def _name(localizer: object) -> str:
    """A localizer's name: the registered name given, or its object's ``name`` (else its class's)."""
    return localizer if isinstance(localizer, str) else str(getattr(localizer, "name", type(localizer).__name__))


@overload
def simulate(options: SimOptions, *, progress: OnProgress | None = None) -> SimResult: ...
@overload
def simulate(
    trajectory: Trajectory | StrPath | None = None,
    *,
    method: str | Strategy = ...,
    robots: int = ...,
    configs: int = ...,
    seed: int = ...,
    model: ModelConfig | None = ...,
    localizer: str | Localizer = ...,
    selection: SelectionConfig | None = ...,
    initial_delta_m: float = ...,
    initial_heading_sigma_rad: float = ...,
    progress: OnProgress | None = None,
    world: str = ...,
    physics: PhysicsParams | None = ...,
) -> SimResult: ...
def simulate(options: SimOptions | Trajectory | StrPath | None = None, /, *, progress: OnProgress | None = None, **keywords: Any) -> SimResult:
    """Run the ``SimOptions`` ``options`` in the in-process simulator, or, as keywords, the ``SimOptions`` they make
    (the first argument then is the ``trajectory``; ``model=None`` and ``selection=None`` are the defaults):
    ``simulate(SimOptions(robots=6, method="ref57"))`` is ``simulate(robots=6, method="ref57")``. ``progress`` is told
    ``(configurations done, of total)``. Everything random derives from ``seed``; the result holds every step's
    estimate and the truth, and in the physical world its contacts and stalls (``result.world_events``): a ``SimResult``
    (a ``RunResult`` with the options it ran; ``to_json()`` is the ``swarm sim --json`` object)."""
    from coordinator.executor import InchwormExecutor  # noqa: PLC0415
    from coordinator.localization import make_localizer  # noqa: PLC0415
    from coordinator.simulate import initial_estimate  # noqa: PLC0415
    from coordinator.strategies import make_strategy  # noqa: PLC0415
    from runtime.models.simulation import SimulatedSwarm  # noqa: PLC0415
    from runtime.models.trajectory import validate_connected, validate_passable  # noqa: PLC0415

    o = _options_of(options, keywords)
    cfg = o.model
    traj = o.run_trajectory()
    validate_connected(traj, cfg.sensing_range_m)
    validate_passable(traj, cfg)
    loc = make_localizer(o.localizer, cfg) if isinstance(o.localizer, str) else o.localizer
    strategy = make_strategy(o.method, traj.n, cfg, loc, o.selection, o.seed) if isinstance(o.method, str) else o.method
    start = initial_estimate(traj, o.seed, o.initial_delta_m, o.initial_heading_sigma_rad)
    if o.world == "physics":
        from runtime.world.params import PhysicsParams  # noqa: PLC0415 - the physics extra, only when asked for
        from runtime.world.swarm import PhysicsSwarm  # noqa: PLC0415

        physical = PhysicsSwarm(traj.ids, traj.initial_poses, o.physics or PhysicsParams.for_model(cfg), o.seed)
        try:
            result = InchwormExecutor(physical, loc, strategy, cfg, progress).run(traj, start)
        finally:
            physical.close()
        result.world_events = physical.events
    else:
        result = InchwormExecutor(SimulatedSwarm(traj.ids, traj.initial_poses, cfg, o.seed), loc, strategy, cfg, progress).run(traj, start)
    return SimResult.of(result, replace(o, trajectory=traj))


def _options_of(options: SimOptions | Trajectory | StrPath | None, keywords: dict[str, Any]) -> SimOptions:
    """``simulate``'s options: the ``SimOptions`` given (first or as ``options=``), or those of its keywords (the
    first argument: the trajectory)."""
    if options is None and isinstance(keywords.get("options"), SimOptions):
        options = keywords.pop("options")
    if isinstance(options, SimOptions):
        if keywords:
            raise TypeError(f"simulate() takes SimOptions or keywords, not both (got {', '.join(sorted(keywords))} too): "
                            "dataclasses.replace(options, ...) changes some")
        return options
    if options is not None:
        if "trajectory" in keywords:
            raise TypeError("simulate() got the trajectory twice: as its first argument and as trajectory=")
        keywords = {**keywords, "trajectory": options}
    return SimOptions(**{k: v for k, v in keywords.items() if v is not None or k not in ("model", "selection")})


def config_rows(result: RunResult) -> list[dict[str, Any]]:
    """Per configuration: n_a (of the strategy's plan), steps taken, e_l (m), following error (m), average distance
    travelled (m); empty without truth."""
    if not result.has_truth:
        return []
    e_l, follow, travelled = result.localization_errors(), result.following_errors(), result.travelled()
    anchors = result.anchor_counts()
    return [{"config": c + 1, "n_a": int(anchors[c]), "steps": rec.n_steps, "e_l": float(e_l[c]),
             "following_error": float(follow[c]), "travelled": float(travelled[c])} for c, rec in enumerate(result.configs)]


def fallback_steps(result: RunResult) -> list[StepRecord]:
    """The steps that kept dead reckoning (some robots could not be localized)."""
    return [s for s in result.steps if s.fallback]


def config_table(result: RunResult) -> str:
    """The per-configuration table (e_l and following error in mm), a line for each plan the body constraint
    regrouped, the steps that kept dead reckoning, and per configuration who stood still and why that many
    (``anchor_choices``)."""
    lines = [f"{'config':>6} {'n_a':>4} {'steps':>5} {'e_l (mm)':>9} {'follow (mm)':>11} {'travelled (m)':>13}"]
    rows, anchors = config_rows(result), result.anchor_counts()
    for c, rec in enumerate(result.configs):
        if rows:
            r = rows[c]
            lines.append(f"{c + 1:>6} {r['n_a']:>4} {r['steps']:>5} {r['e_l'] * 1e3:>9.2f} {r['following_error'] * 1e3:>11.2f} "
                         f"{r['travelled']:>13.3f}")
        else:
            lines.append(f"{c + 1:>6} {anchors[c]:>4} {rec.n_steps:>5} {'-':>9} {'-':>11} {'-':>13}")
    lines += [f"config {c + 1}: {rec.regrouped.describe(rec.plan.n_steps)}" for c, rec in enumerate(result.configs) if rec.regrouped]
    short = result.stopped_short()
    lines += [f"config {c + 1}: {legs_text(rec, short[c])}" for c, rec in enumerate(result.configs) if rec.legs]
    lines += [f"config {s.config + 1} step {s.step + 1}: kept dead reckoning ({s.fallback})" for s in fallback_steps(result)]
    return "\n".join([*lines, *anchor_choices(result)])


def legs_text(rec: ConfigRecord, stopped_short: list[int] | None = None) -> str:
    """How a configuration's movers drove in approach legs (``coordinator.legs``), and the robots they stopped short of
    their desired positions (``RunResult.stopped_short``)."""
    waits = f", {rec.holds} waits for a neighbour" if rec.holds else ""
    waits += f", {rec.corrections} corrections of a robot left at risk" if rec.corrections else ""
    waits += f", {rec.legs_cut} legs cut short (a touch, or the next step at risk)" if rec.legs_cut else ""
    waits += f", {rec.deferred} robots stood in a step at risk" if rec.deferred else ""
    text = (f"approach legs for bodies: {len(rec.legs)} legs, {rec.staging_stops} stops at a staging point{waits}, "
            f"steps {rec.plan.n_steps} -> {rec.n_steps}")
    if stopped_short:
        text += f"; robots {stopped_short} stopped short of their targets (at risk there even with no motion noise, or blocked by a standing robot)"
    return text


def _robots(ids: list[int], most: int = 20) -> str:
    """Robot ids as ranges (``0-3,7``); a long list as its count and first ids."""
    from robot_agent.assembly import format_ids  # noqa: PLC0415 - the id-range text the agents' --ids take

    if not ids:
        return "none"
    return format_ids(ids) if len(ids) <= most else f"{len(ids)} robots ({format_ids(ids[:most])}, ...)"


def anchor_choices(result: RunResult) -> list[str]:
    """Per configuration: which robots stood still at each step and, where the plan was searched, the outer
    loop's score of every candidate count (Eq. 3: P_s = w_v P_v - w_l P_l, P_v = 1 / n_s, P_l = e_l / e_l(0),
    e_l the Monte Carlo estimate of the count's best plan, in mm); the chosen count is marked ``*``. The counts
    without a plan (none keeps the bodies apart, or the swarm connected) are one line per reason below the table."""
    lines = []
    for c in result.configs:
        plan = c.plan if c.regrouped is None else c.regrouped.planned  # the strategy's (the steps taken: ``c.plan``)
        still = "; ".join(f"step {k + 1}: {_robots(sorted(c.anchor_ids(k).tolist()))}" for k in range(c.plan.n_steps))
        who = "no anchors, every robot moved at once" if c.plan.n_anchors == 0 else f"stood still {still}"
        lines.append(f"config {c.config + 1}: n_a = {plan.n_anchors} ({who})")
        if c.selection is None or len(c.selection.scores) < 2:
            continue
        lines.append(f"  {'n_a':>5} {'steps':>5} {'e_l (mm)':>9} {'P_v':>6} {'P_l':>6} {'P_s':>7}")
        unplanned: dict[str, list[int]] = {}
        for s in c.selection.scores:
            if s.plan is None:  # summarised below the scored rows, one line per reason
                why = "no plan found keeps bodies apart" if s.crowded else "no plan keeps the swarm connected"
                unplanned.setdefault(why, []).append(s.n_anchors)
                continue
            mark = "*" if s.n_anchors == plan.n_anchors else " "
            steps = round(1 / s.p_v) if s.p_v > 0 else 0
            lines.append(f"  {mark}{s.n_anchors:>4} {steps:>5} {s.e_l * 1e3:>9.2f} {s.p_v:>6.3f} {s.p_l:>6.3f} {s.p_s:>7.3f}")
        lines += [f"   n_a = {', '.join(map(str, counts))}: {why}" for why, counts in unplanned.items()]
    if any(c.selection is not None and len(c.selection.scores) > 1 for c in result.configs):
        lines.append("  (* chosen: the count of highest P_s = w_v P_v - w_l P_l, Eq. 3; P_v = 1/steps; P_l = e_l / e_l(n_a = 0)"
                     " on the same samples; e_l: Monte Carlo estimate of the count's best plan)")
    return lines


def contacts_text(result: RunResult, radius: float) -> str:
    """The contacts of the robots' true bodies of ``radius`` (m) and the steps added for bodies ("" for point robots)."""
    if radius <= 0 or not result.has_truth:
        return ""
    contacts = result.contacts(radius)
    closest = f", closest {min(c.distance for c in contacts) * 1e3:.1f} mm" if contacts else ""
    stops = f"; stops at a staging point: {result.staging_stops()}" if result.staging_stops() else ""
    lines = [f"contacts (bodies of radius {radius:g} m): {len(contacts)}{closest}; steps added for bodies: {result.steps_added()}{stops}"]
    lines += [f"  step {c.step} (config {c.config + 1}): robots {c.a} and {c.b}, centres {c.distance * 1e3:.1f} mm apart" for c in contacts]
    return "\n".join(lines)


def contacts_json(result: RunResult, radius: float) -> dict[str, Any]:
    """The additive ``--json`` keys of a run's bodies: ``robot_radius_m``, ``steps_added``, ``contacts``
    (each ``step``, ``config`` 1-based, ``robots`` [a, b], ``distance_m``) and ``regrouped`` (each configuration
    whose plan the chance constraint split: ``config`` 1-based, ``planned_steps``, ``steps``, ``contact_bound`` the
    highest bound per pair and step kept, ``unclear`` the robots no order kept within the highest, moved one at a time),
    ``staging_stops`` (approach legs driven to a staging point, ``coordinator.legs``) and ``legs`` (each configuration
    whose movers drove in approach legs: ``config`` 1-based, ``legs``, ``staging_stops``, ``steps``, ``stopped_short``
    the robots the legs stopped short of their desired positions, at risk there even with no motion noise or blocked by
    a robot standing for the rest of the change, ``holds`` the legs a robot waited in for a neighbour),
    ``stopped_short`` (those robots over the run, one per robot and configuration), ``holds`` (the waits over the
    run) and ``corrections`` (legs a robot drove as a correction after standing at risk, ``coordinator.legs``; also per
    configuration with legs), ``legs_cut`` (legs ended before their last group: a step left two robots touching, or the next
    step was at risk, ``coordinator.legs.new_touches``, ``deferred_movers``; also per configuration with legs) and
    ``deferred`` (robots that stood in their step of a leg because it was at risk; also per configuration with legs)."""
    short = result.stopped_short()
    return {"robot_radius_m": radius, "steps_added": result.steps_added(), "staging_stops": result.staging_stops(),
            "stopped_short": sum(len(s) for s in short), "holds": result.holds(), "corrections": result.corrections(),
            "legs_cut": sum(c.legs_cut for c in result.configs), "deferred": sum(c.deferred for c in result.configs),
            "legs": [{"config": k + 1, "legs": len(c.legs), "staging_stops": c.staging_stops, "steps": c.n_steps,
                      "stopped_short": short[k], "holds": c.holds, "corrections": c.corrections, "legs_cut": c.legs_cut,
                      "deferred": c.deferred}
                     for k, c in enumerate(result.configs) if c.legs],
            "contacts": [{"step": c.step, "config": c.config + 1, "robots": [c.a, c.b], "distance_m": c.distance}
                         for c in result.contacts(radius)],
            "regrouped": [{"config": k + 1, **c.regrouped.to_json(c.plan.n_steps)} for k, c in enumerate(result.configs) if c.regrouped]}


def summary_text(result: RunResult, method: str, localizer: str, radius: float = 0.0) -> str:
    """The table of a distributed run, its contacts (bodies of ``radius`` m), the robots it lost and its P_f
    (over the robots that finished)."""
    lines = [config_table(result)]
    if contacts_text(result, radius):
        lines.append(contacts_text(result, radius))
    lines += [f"lost robot {lost.robot} after step {lost.step} (config {lost.config + 1}): {lost.reason}" for lost in result.lost]
    lines += [f"robot {back.robot} rejoined after step {back.step}, from config {back.config + 1} on" for back in result.rejoined]
    pf = result.pf() if result.has_truth and result.configs else None
    over = f", over the {len(result.finished_ids)} robots that finished" if result.lost else ""
    lines.append(f"P_f = {pf:.4f} ({method}, {localizer} localizer, distributed{over})" if pf is not None else "P_f: no ground truth")
    return "\n".join(lines)


def write_run_outputs(result: RunResult, result_path: Path | None, plots_dir: Path | None) -> tuple[list[str], list[str]]:
    """Write a distributed run's ``--result`` JSON and plots: (the plot files, one line per output that failed)."""
    import json  # noqa: PLC0415 - only when a run ends

    from coordinator.node.process import result_json  # noqa: PLC0415
    from inchworm.plots import write_run_plots  # noqa: PLC0415

    plots: list[str] = []
    errors: list[str] = []
    if result_path:
        try:
            result_path.write_text(json.dumps(result_json(result)))
        except OSError as exc:
            errors.append(f"cannot write --result {result_path}: {exc.strerror or exc}")
    if plots_dir and result.configs:
        try:
            plots = write_run_plots(result, plots_dir)
        except OutputError as exc:  # a figure that could not be written (inchworm.plots.save_figure): the file and why
            errors.append(str(exc))
    return plots, errors


def run_json(result: RunResult, method: str, localizer: str, seed: int, plots: list[str], recording: str | None,
             radius: float, ended_early: str | None = None) -> dict[str, Any]:
    """The ``--json`` object of a distributed run (``swarm coordinator``, ``swarm launch``); ``ended_early``: why the
    run ended before its last configuration (lost robots, the hub lost, a recording failure), None if it did not."""
    return {"method": method, "localizer": localizer, "seed": seed, "pf": result.pf() if result.has_truth and result.configs else None,
            "configs": config_rows(result), "lost": [{"robot": r.robot, "step": r.step, "reason": r.reason} for r in result.lost],
            "finished_robots": len(result.finished_ids), "fallback_steps": len(fallback_steps(result)), "plots": plots,
            "recording": recording, **contacts_json(result, radius), "ended_early": ended_early}


def world_text(result: RunResult) -> str:
    """The physical world's contacts and stalls of a run ("" for a run in the noise model's world)."""
    from runtime.world.physics import Contact, Stuck  # noqa: PLC0415

    contacts = [(s, e) for s, e in result.world_events if isinstance(e, Contact)]
    stuck = [(s, e) for s, e in result.world_events if isinstance(e, Stuck)]
    if not result.world_events:
        return ""
    lines = [f"physical world: {len(contacts)} contacts between {len({(e.a, e.b) for _, e in contacts})} pairs, "
             f"{len(stuck)} stalled drives"]
    lines += [f"  step {s}: robots {e.a} and {e.b} touched at t = {e.start_s:.2f} s, impulse {e.impulse_n_s * 1e3:.2f} mN s"
              for s, e in contacts[:20]]
    lines += [f"  step {s}: robot {e.robot} stalled: drove {e.achieved_m * 1e3:.0f} of {e.commanded_m * 1e3:.0f} mm" for s, e in stuck[:20]]
    return "\n".join(lines)


def world_json(result: RunResult, world: str) -> dict[str, Any]:
    """The additive ``--json`` keys of the world: ``world`` and, for ``physics``, ``world_contacts`` (each ``step``,
    ``robots`` [a, b], ``start_s``, ``end_s`` (null: still touching), ``point``, ``impulse_n_s``) and ``world_stuck``
    (each ``step``, ``robot``, ``commanded_m``, ``achieved_m``)."""
    if world != "physics":
        return {"world": world}
    from runtime.world.physics import Contact, Stuck  # noqa: PLC0415

    return {"world": world,
            "world_contacts": [{"step": s, "robots": [e.a, e.b], "start_s": e.start_s, "end_s": e.end_s, "point": list(e.point),
                                "impulse_n_s": e.impulse_n_s} for s, e in result.world_events if isinstance(e, Contact)],
            "world_stuck": [{"step": s, "robot": e.robot, "commanded_m": e.commanded_m, "achieved_m": e.achieved_m}
                            for s, e in result.world_events if isinstance(e, Stuck)]}
