"""Replaying a recording: publish its messages again (``publish``) or check that the coordinator
reproduces it (``check_recording``); ``swarm replay`` parses options, calls these and prints.

``publish`` re-publishes every recorded message of the run (every channel under ``swarm/``;
derived channels such as ``/foxglove/...`` are not Zenoh messages and are left out; file order,
bytes unchanged, on its recorded key) with the recorded relative timing (log time) divided by
``speed`` (``0`` or ``inf``: as fast as possible). With ``hub`` it joins that hub as a client;
without it, the hub of the recorded run if that run is live on this host (its run file,
``runtime.wire.run_file``); otherwise it opens its own loopback hub (a Zenoh router on a free
port) and keeps a run file for the recorded run id while it publishes. It waits up to ``wait``
seconds for a subscriber of any recorded key before it starts. Puts use Zenoh's blocking
congestion control, so nothing is dropped. Unless ``same_run``, the messages are published under
a new run id (``run_id``, default ``<run>-replay-<6 hex digits>``): each message's ``run`` and key
are rewritten, nothing else. Either way it first asks the hub whether an agent or a coordinator
of that run id is alive and refuses (``SwarmInputError`` naming them) if one is.

``check_recording`` re-runs the coordinator's localization (and, where the metadata allows, its
initial estimate and seeded anchor selection) on the recorded inputs and compares every result
with the recorded estimate / plan bit for bit (``coordinator.replay_check``). Options fill in
settings the recording's metadata lacks; one that contradicts a recorded setting is refused
naming the recorded value, unless ``what_if``.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable
from dataclasses import KW_ONLY, dataclass, field
from typing import TYPE_CHECKING, Any, cast

from inchworm.limits import MODEL_FLAGS
from runtime.errors import OptionError, SwarmInputError, mentions
from runtime.paths import StrPath, as_path, coerce_paths
from runtime.wire.keys import ROOT, KeyspaceError, validate_run

if TYPE_CHECKING:
    import zenoh

    from coordinator.replay_check import RecordedRun

MODEL_OPTIONS = {dest: (name, convert) for dest, (name, convert, _) in MODEL_FLAGS.items()}  # option dest -> (ModelConfig field, to SI)
SELECTION_OPTIONS = ("w_v", "samples", "population", "generations", "selection", "mc_start", "mc_emax")
Say = Callable[[str], None]


def _quiet(_text: str) -> None:
    return None


@dataclass(frozen=True)
class PublishOptions:
    """What ``publish`` sends and where (module doc); ``speed``: time scale, ``wait``: seconds."""

    file: StrPath
    _: KW_ONLY  # the file positional, the rest by keyword
    speed: float = field(default=1.0, metadata={"help": "time scale (default 1 = recorded timing; 0 or inf: as fast as possible)",
                                                 "own_default": True})
    hub: str | None = field(default=None, metadata={"help": "Zenoh endpoint of a hub to join (default: the hub of the recorded run if it "
                                                            "is live on this host, else a loopback hub of its own, printed)"})
    wait: float = field(default=10.0, metadata={"help": "seconds to wait for a subscriber before publishing"})
    run_id: str | None = field(default=None, metadata={"flag": "--run", "help": "run id to publish under (default <run>-replay-<hex>)"})
    same_run: bool = field(default=False, metadata={"help": "publish under the recorded run id, bytes unchanged"})

    def __post_init__(self) -> None:
        coerce_paths(self, "file")
        if math.isnan(self.speed) or self.speed < 0:
            raise OptionError("speed", f"must be >= 0 (0 or inf: as fast as possible), got {self.speed}", self)
        if not self.wait >= 0:
            raise OptionError("wait", f"must be >= 0, got {self.wait}", self)


@dataclass(frozen=True)
class PublishResult:
    messages: int
    keys: int
    elapsed_s: float
    recorded_s: float
    hub: str
    skipped: int  # messages of derived channels (outside ``swarm/``), not published
    fast: bool  # as fast as possible (speed 0 or inf)

    def to_json(self) -> dict[str, Any]:
        return {"messages": self.messages, "keys": self.keys, "elapsed_s": self.elapsed_s, "recorded_s": self.recorded_s,
                "hub": self.hub, "skipped": self.skipped}


def _valid_run(run: str) -> bool:
    try:
        validate_run(run)
    except KeyspaceError:
        return False
    return True


def publish(options: PublishOptions, *, say: Say = _quiet, warn: Say = _quiet) -> PublishResult:
    """Publish the recording ``options.file`` (module doc); ``say``: where it publishes, ``warn``: progress."""
    import zenoh  # noqa: PLC0415 - only when publishing

    from runtime.recording.mcap_log import read_messages, recording_info  # noqa: PLC0415
    from runtime.wire.run_file import published_run, read_run  # noqa: PLC0415
    from runtime.wire.transport import ZenohSettings, free_tcp_port, loopback_hub, open_session  # noqa: PLC0415

    speed = options.speed
    info = recording_info(options.file)  # the whole file is validated before anything is published
    everything = list(read_messages(options.file))
    messages = [m for m in everything if m[0].startswith(ROOT + "/")]  # the run's Zenoh messages, not derived views
    skipped = len(everything) - len(messages)
    if not info["complete"]:
        warn(f"swarm replay: {options.file} is unfinished ({info['problem'] or 'no summary'}): replaying its "
             f"{len(messages)} readable messages")
    messages, run = _retarget(messages, options.run_id, options.same_run)  # a new run id unless same_run
    live = read_run(run) if isinstance(run, str) and _valid_run(run) else None
    own_run: contextlib.AbstractContextManager[Any] = contextlib.nullcontext()
    if options.hub:
        settings, hub, where = ZenohSettings("client", connect=(options.hub,)), options.hub, "--hub"
    elif live is not None:
        settings, hub = ZenohSettings("client", connect=(live["hub"],)), live["hub"]
        where = f"the hub of live run {run} (run file {live['path']})"
    else:
        port = free_tcp_port()
        settings, _ = loopback_hub(port)
        hub = f"tcp/127.0.0.1:{port}"
        where = "a hub this command opened on loopback"
        if isinstance(run, str) and _valid_run(run):
            own_run = published_run(run, hub, "swarm replay --publish")
            where += f"; on this host `--run {run}` finds it (swarm record --run {run}, swarm estop --run {run})"
        else:
            where += f"; connect with --hub {hub}"
    with open_session(settings) as session, own_run:  # the hub is open, and findable, before anyone is told of it
        _refuse_live_run(session, run)  # a replay never publishes onto a live run
        say(f"swarm replay: publishing {len(messages)} messages of run {run or '?'} on {hub} ({where})")
        publishers: dict[str, Any] = {}  # zenoh.Publisher (its stub types matching_status as a bool)
        for topic, *_ in messages:
            if topic not in publishers:
                publishers[topic] = session.declare_publisher(topic, congestion_control=zenoh.CongestionControl.BLOCK)
        warn(f"swarm replay: {len(messages)} messages on {len(publishers)} keys; "
             f"waiting up to {options.wait:g} s for a subscriber")
        deadline = time.monotonic() + options.wait
        while publishers and not any(p.matching_status.matching for p in publishers.values()):
            if time.monotonic() >= deadline:
                warn("swarm replay: no subscriber; publishing anyway")
                break
            time.sleep(0.01)
        fast = speed == 0 or math.isinf(speed)
        start = time.monotonic()
        first = messages[0][2] if messages else 0
        for topic, payload, log_time, _pub in messages:
            if not fast:
                wait = start + (log_time - first) / 1e9 / speed - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
            publishers[topic].put(payload)
        elapsed = time.monotonic() - start
        time.sleep(0.5)  # let the last samples leave before the session (and, own hub, the router) closes
        for p in publishers.values():
            p.undeclare()
    span = (messages[-1][2] - first) / 1e9 if messages else 0.0
    return PublishResult(len(messages), len(publishers), elapsed, span, hub, skipped, fast)


def _retarget(messages: list[tuple[str, bytes, int, int]], run_id: str | None, same_run: bool) -> tuple[list[tuple[str, bytes, int, int]], str]:
    """The messages to publish and their run id: the recorded one (``same_run``), else ``run_id`` or a new one,
    each message's ``run`` and key rewritten (an undecodable recorded message keeps its bytes)."""
    import dataclasses  # noqa: PLC0415
    import secrets  # noqa: PLC0415

    from runtime.wire.keys import parse_key  # noqa: PLC0415
    from runtime.wire.messages import MessageError, decode, encode  # noqa: PLC0415

    recorded = sorted({parse_key(topic).run for topic, *_ in messages if _parses(topic)})
    if len(recorded) > 1:
        raise SwarmInputError(f"the recording holds several runs ({', '.join(recorded)}): cannot choose one to replay")
    source = recorded[0] if recorded else None
    if same_run or source is None:
        return messages, source or "(none)"
    target = run_id or f"{source[:50]}-replay-{secrets.token_hex(3)}"
    try:
        validate_run(target)
    except SwarmInputError as exc:
        raise OptionError("run_id", f"{target!r}: {exc}", PublishOptions) from None
    if target == source:
        return messages, target
    old, new = f"{ROOT}/{source}/", f"{ROOT}/{target}/"
    out = []
    for topic, payload, log_time, pub in messages:
        try:
            payload = encode(dataclasses.replace(decode(payload, key=topic), run=target))
        except MessageError:
            pass  # recorded as it was received (e.g. a hostile message): its bytes, on the new key
        out.append((new + topic[len(old):] if topic.startswith(old) else topic, payload, log_time, pub))
    return out, target


def _parses(topic: str) -> bool:
    from runtime.wire.keys import parse_key  # noqa: PLC0415

    try:
        parse_key(topic)
    except KeyspaceError:
        return False
    return True


def _refuse_live_run(session: zenoh.Session, run_id: str) -> None:
    """``SwarmInputError`` naming them if an agent or a coordinator of ``run_id`` is alive on this hub (``live_run``:
    a spurious empty answer is asked past)."""
    from coordinator.node.zenoh_backend import live_run  # noqa: PLC0415

    if run_id == "(none)":
        return
    live = live_run(session, run_id)
    robots, coords = sorted(live.robots), sorted(live.coordinators)
    if robots or coords:
        who = ", ".join(([f"coordinator epoch {', '.join(map(str, coords))}"] if coords else [])
                        + ([f"agents of robots {', '.join(map(str, robots))}"] if robots else []))
        raise OptionError("run_id", f"{run_id} is live on this hub ({who}): a replay never publishes onto a live run; "
                                    f"publish under a new run id (the default, or `run_id` NEW)", PublishOptions)


# ------------------------------------------------------------------ check


@dataclass(frozen=True)
class CheckOptions:
    """Settings of ``check_recording``; None: the recorded one. ``model_flags``: ``MODEL_OPTIONS`` dest -> value as
    typed (degrees for angles), ``selection``: ``SELECTION_OPTIONS`` dest -> value."""

    file: StrPath
    _: KW_ONLY  # the file positional, the rest by keyword
    localizer: str | None = None
    seed: int | None = field(default=None, metadata={"help": "seed of the initial estimate and the anchor search"})
    trajectory: StrPath | None = field(default=None, metadata={"help": "trajectory JSON, if the recording has none in its metadata"})
    model_file: StrPath | None = field(default=None, metadata={"flag": "--model"})
    model_flags: dict[str, float] = field(default_factory=dict)
    selection: dict[str, Any] = field(default_factory=dict)
    what_if: bool = field(default=False, metadata={"help": "allow options that contradict the recording's metadata (refused otherwise): "
                                                           "re-run with them and report where the results part"})

    def __post_init__(self) -> None:
        coerce_paths(self, "file", "trajectory", "model_file")


@dataclass(frozen=True)
class CheckOutcome:
    """A ``coordinator.replay_check`` result, with the overrides used and the options that contradict the recording
    (``against``: ``localizer joint (recorded: paper)``; ``against_flags``: the same as the command line says it,
    ``--localizer joint (recorded: paper)``)."""

    result: Any  # coordinator.replay_check.CheckResult
    model: dict[str, float]
    selection: dict[str, Any]
    against: list[str]
    against_flags: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        r, d = self.result, self.result.divergence
        return {"passed": r.passed, "exact": r.exact, "estimates": r.estimates, "plans": r.plans, "skipped": r.skipped,
                "divergence": None if d is None else {"step": d.step, "what": d.what, "robot": d.robot, "field": d.field,
                                                      "recorded": d.recorded, "recomputed": d.recomputed}}


def _overrides(options: CheckOptions) -> tuple[dict[str, Any], dict[str, Any]]:
    from runtime.models.model_file import load_model  # noqa: PLC0415

    model = load_model(options.model_file).to_dict() if options.model_file is not None else {}  # a model file replaces the recorded model
    model |= {field: convert(options.model_flags[name]) for name, (field, convert) in MODEL_OPTIONS.items()
              if options.model_flags.get(name) is not None}
    selection = {name: options.selection[name] for name in SELECTION_OPTIONS if options.selection.get(name) is not None}
    if "w_v" in selection and not 0.0 <= selection["w_v"] <= 1.0:
        raise OptionError("w_v", f"must be in [0, 1], got {selection['w_v']}")
    return model, selection


def _recorded_selection_values(meta: dict[str, Any]) -> dict[str, Any]:
    """The selection options as the recording's metadata states them (only those it states)."""
    stored = meta.get("selection")
    if not isinstance(stored, dict):
        return {}
    genetic = stored.get("genetic")
    if not isinstance(genetic, dict):
        genetic = {}
    values = {"w_v": stored.get("w_v"), "samples": stored.get("samples"), "selection": stored.get("method"),
              "population": genetic.get("population"), "generations": genetic.get("generations")}
    return {k: v for k, v in values.items() if v is not None}


def contradictions(rec: RecordedRun, options: CheckOptions, model: dict[str, Any], selection: dict[str, Any]) -> list[str]:
    """The options given that differ from what the recording's metadata states, as ```name` VALUE (recorded: X)`` (the
    option in backquotes: ``runtime.errors.mentions`` gives its Python name or its flag);
    model options equal to the recorded value up to rounding are removed from ``model`` (the recorded value is used)."""
    meta, found = rec.meta, []
    typed = {"localizer": options.localizer, "seed": options.seed, **options.model_flags, **options.selection}

    def differs(a: object, b: object) -> bool:
        if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
            return not math.isclose(float(a), float(b), rel_tol=1e-12, abs_tol=0.0)
        return a != b

    def note(dest: str, given: Any, recorded: Any, shown: Any = None) -> None:  # values as given and as recorded (JSON)
        if differs(given, recorded):
            shown_recorded = recorded if shown is None else shown
            value = typed.get(dest)
            named = f"`{dest}` {value}" if value is not None else f"`model_file` {options.model_file}: {dest} {shown_given(dest, given)}"
            found.append(f"{named} (recorded: {shown_recorded})")

    def shown_given(dest: str, value: float) -> str:
        return f"{math.degrees(value):g}" if MODEL_OPTIONS.get(dest, (None, None))[1] is math.radians else f"{value:g}"

    if options.localizer is not None and "localizer" in meta:
        note("localizer", options.localizer, meta["localizer"])
    if options.seed is not None and "seed" in meta:
        note("seed", options.seed, meta["seed"])
    stored_model = cast("dict[str, Any]", meta.get("model") if isinstance(meta.get("model"), dict) else {})  # a dict: checked
    for dest, (field_name, convert) in MODEL_OPTIONS.items():
        if field_name in model and field_name in stored_model:
            recorded = float(stored_model[field_name])
            shown = f"{math.degrees(recorded):g}" if convert is math.radians else f"{recorded:g}"
            note(dest, model[field_name], recorded, shown)
            if not differs(model[field_name], recorded):  # the recorded value as typed (3 for 3.0000000000000004 deg): keep the exact one
                del model[field_name]
    for dest, recorded in _recorded_selection_values(meta).items():
        if dest in selection:
            note(dest, selection[dest], recorded)
    if options.trajectory is not None and isinstance(meta.get("trajectory"), dict):
        from runtime.models.trajectory import Trajectory  # noqa: PLC0415

        if Trajectory.load(options.trajectory).to_json() != meta["trajectory"]:
            found.append(f"`trajectory` {options.trajectory} (the recording has another trajectory in its metadata)")
    return found


def check_recording(options: CheckOptions, *, warn: Say = _quiet) -> CheckOutcome:
    """Re-run the recording's localization and anchor selection and compare (module doc); ``warn``: notes."""
    from coordinator.replay_check import check, load_recording  # noqa: PLC0415 - scipy when checking

    model, selection = _overrides(options)
    rec = load_recording(options.file)
    if not rec.complete:
        warn(f"swarm replay: {options.file} is unfinished ({rec.info['problem'] or 'no summary'}): checking what it holds")
    against = contradictions(rec, options, model, selection)
    if against and not options.what_if:
        raise OptionError(
            "what_if", f"is not set and {', '.join(against)} contradicts {options.file}: the check reproduces the recorded run "
            f"with its own settings, so leave these options out (they are for recordings whose metadata lacks them), or set "
            f"`what_if` to re-run the recorded inputs with them (the check then reports where the results part)", options)
    flags = [mentions(text, options, flags=True) for text in against]
    if against:
        warn(f"swarm replay: what-if: {', '.join(flags)}: the recorded results are not expected to be reproduced")
    result = check(rec, localizer=options.localizer, model=model, selection=selection, seed=options.seed,
                   trajectory=as_path(options.trajectory) if options.trajectory is not None else None)
    return CheckOutcome(result, model, selection, [mentions(text) for text in against], flags)
