"""``swarm replay``: publish a recording again, or check that the coordinator reproduces it.

    swarm replay FILE --publish [--speed X] [--hub tcp/127.0.0.1:PORT] [--wait S]
    swarm replay FILE --check [--localizer L] [model / selection options] [--seed N] [--trajectory FILE]

``--publish`` re-publishes every recorded message of the run (every channel under
``swarm/``; derived channels such as ``/foxglove/...`` are not Zenoh messages and are left
out; file order, bytes unchanged, on its recorded key) with the recorded relative timing (log time) divided by ``--speed``
(default 1; ``0`` or ``inf``: as fast as possible). It says on stdout where it publishes:
with ``--hub`` it joins that hub as a client; without it, the hub of the recorded run if that
run is live on this host (its run file, ``swarm_cli.run_file``); otherwise it opens its own
loopback hub (a Zenoh router on a free port) and keeps a run file for the recorded run id
while it publishes, so ``swarm record --run RUN`` or a live view on this host finds it. It waits up to
``--wait`` seconds (default 10) for a subscriber of any recorded key before it starts. Puts use Zenoh's
blocking congestion control, so nothing is dropped.

``--check`` re-runs the coordinator's localization (and, where the metadata allows, its
initial estimate and seeded anchor selection) on the recorded inputs and compares every
result with the recorded estimate / plan bit for bit (``coordinator.replay_check``). Options
fill in settings the recording's metadata lacks (a ``swarm record`` file); an option that
contradicts a recorded setting (``--localizer joint`` on a paper-localizer run) is refused
with exit 2 naming the recorded value, unless ``--what-if`` asks to re-run with it (a warning
says the results are not expected to match). Prints ``check passed: N estimates, M plans
reproduced`` (exit 0) or the first divergence (exit 1).

Files that are not MCAP, damaged or cut inside the header: a message naming the file and
the problem, exit 2. Unfinished (killed) recordings are read up to their last complete chunk.

Unless ``--same-run``, the messages are published under a new run id (``--run NEW``, default
``<run>-replay-<6 hex digits>``, printed): each message's ``run`` and key are rewritten, nothing
else. Either way it first asks the hub whether an agent or a coordinator of that run id is
alive and refuses (exit 2, naming them) if one is: a replay never drives a live run (and its
commands, carrying the recorded coordinator's epoch, would be refused by live agents anyway).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
import time
from pathlib import Path

from runtime.errors import SwarmInputError
from runtime.models.model_file import load_model
from runtime.recording.mcap_log import read_messages, recording_info
from runtime.wire.keys import ROOT, KeyspaceError, validate_run
from swarm_cli.options import add_json_option, add_localizer_option, add_model_options, add_selection_options, print_json
from swarm_cli.run_file import published_run, read_run

EXIT_DIVERGED = 1
MODEL_OPTIONS = {  # option dest -> (ModelConfig field, conversion)
    "turn_sigma_deg": ("turn_sigma_rad", math.radians),
    "drive_sigma_frac": ("drive_sigma_frac", float),
    "range_sigma": ("range_sigma_m", float),
    "bearing_sigma_deg": ("bearing_sigma_rad", math.radians),
    "sensing_range": ("sensing_range_m", float),
    "dropout": ("dropout_prob", float),
    "robot_radius": ("robot_radius_m", float),
}
SELECTION_OPTIONS = ("w_v", "samples", "population", "generations", "selection", "mc_start", "mc_emax")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="re-publish a recording on Zenoh (--publish) or check that it is reproduced (--check)")
    p.add_argument("file", type=Path, help="MCAP recording (swarm coordinator / swarm record)")
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument("--publish", action="store_true", help="publish every recorded message again with its timing")
    mode.add_argument("--check", action="store_true", help="re-run localization and anchor selection, compare bit for bit")
    g = p.add_argument_group("--publish")
    g.add_argument("--speed", type=float, default=1.0, help="time scale (default 1 = recorded timing; 0 or inf: as fast as possible)")
    g.add_argument("--hub", default=None, help="Zenoh endpoint of a hub to join (default: the hub of the recorded run if it is live "
                                               "on this host, else a loopback hub of its own, printed)")
    g.add_argument("--wait", type=float, default=10.0, help="seconds to wait for a subscriber before publishing (default 10)")
    target = g.add_mutually_exclusive_group()
    target.add_argument("--run", dest="run_id", default=None, help="run id to publish under (default <run>-replay-<hex>)")
    target.add_argument("--same-run", action="store_true", help="publish under the recorded run id, bytes unchanged")
    c = p.add_argument_group("--check (options given override the recorded ones)")
    c.add_argument("--seed", type=int, default=None, help="seed of the initial estimate and the anchor search")
    c.add_argument("--trajectory", type=Path, default=None, help="trajectory JSON, if the recording has none in its metadata")
    c.add_argument("--what-if", action="store_true",
                   help="allow options that contradict the recording's metadata (refused otherwise): re-run with them and report "
                        "where the results part")
    add_localizer_option(p)
    add_selection_options(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run, localizer=None, **{name: None for name in (*MODEL_OPTIONS, *SELECTION_OPTIONS)})


def run(args: argparse.Namespace) -> int:
    return run_check(args) if args.check else run_publish(args)


def _valid_run(run: str) -> bool:
    try:
        validate_run(run)
    except KeyspaceError:
        return False
    return True


# ------------------------------------------------------------------ --publish


def run_publish(args: argparse.Namespace) -> int:
    import zenoh  # noqa: PLC0415 - only when publishing

    from runtime.wire.transport import ZenohSettings, free_tcp_port, loopback_hub, open_session  # noqa: PLC0415

    speed = args.speed
    if math.isnan(speed) or speed < 0:
        raise SwarmInputError(f"--speed must be >= 0 (0 or inf: as fast as possible), got {speed}")
    if args.wait < 0:
        raise SwarmInputError(f"--wait must be >= 0, got {args.wait}")
    info = recording_info(args.file)  # the whole file is validated before anything is published
    everything = list(read_messages(args.file))
    messages = [m for m in everything if m[0].startswith(ROOT + "/")]  # the run's Zenoh messages, not derived views
    skipped = len(everything) - len(messages)
    if not info["complete"]:
        print(f"swarm replay: {args.file} is unfinished ({info['problem'] or 'no summary'}): replaying its "
              f"{len(messages)} readable messages", file=sys.stderr, flush=True)
    messages, run = _retarget(messages, args.run_id, args.same_run)  # a new run id unless --same-run
    live = read_run(run) if isinstance(run, str) and _valid_run(run) else None
    own_run = contextlib.nullcontext()
    if args.hub:
        settings, hub, where = ZenohSettings("client", connect=(args.hub,)), args.hub, "--hub"
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
        print(f"swarm replay: publishing {len(messages)} messages of run {run or '?'} on {hub} ({where})", flush=True)
        publishers = {}
        for topic, *_ in messages:
            if topic not in publishers:
                publishers[topic] = session.declare_publisher(topic, congestion_control=zenoh.CongestionControl.BLOCK)
        print(f"swarm replay: {len(messages)} messages on {len(publishers)} keys; "
              f"waiting up to {args.wait:g} s for a subscriber", file=sys.stderr, flush=True)
        deadline = time.monotonic() + args.wait
        while publishers and not any(p.matching_status.matching for p in publishers.values()):
            if time.monotonic() >= deadline:
                print("swarm replay: no subscriber; publishing anyway", file=sys.stderr, flush=True)
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
    print(f"replayed {len(messages)} messages on {len(publishers)} keys in {elapsed:.3f} s "
          f"(recorded span {span:.3f} s, speed {'max' if fast else f'{speed:g}'})"
          + (f"; {skipped} messages of derived channels (outside {ROOT}/) not published" if skipped else ""), flush=True)
    if args.json:
        print_json({"messages": len(messages), "keys": len(publishers), "elapsed_s": elapsed, "recorded_s": span, "hub": hub,
                    "skipped": skipped})
    return 0


def _retarget(messages: list[tuple[str, bytes, int, int]], run_id: str | None, same_run: bool) -> tuple[list, str]:
    """The messages to publish and their run id: the recorded one (``same_run``), else ``run_id`` or a new one,
    each message's ``run`` and key rewritten (an undecodable recorded message keeps its bytes)."""
    import dataclasses  # noqa: PLC0415
    import secrets  # noqa: PLC0415

    from runtime.wire.keys import parse_key, validate_run  # noqa: PLC0415
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
        raise SwarmInputError(f"--run {target!r}: {exc}") from None
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
    from runtime.wire.keys import KeyspaceError, parse_key  # noqa: PLC0415

    try:
        parse_key(topic)
    except KeyspaceError:
        return False
    return True


def _refuse_live_run(session, run_id: str) -> None:
    """``SwarmInputError`` naming them if an agent or a coordinator of ``run_id`` is alive on this hub."""
    from coordinator.zenoh_backend import live_coordinators  # noqa: PLC0415
    from runtime.wire.keys import alive_wildcard, parse_key  # noqa: PLC0415
    from runtime.wire.transport import alive_now  # noqa: PLC0415

    if run_id == "(none)":
        return
    robots = sorted(parse_key(key).robot for key in alive_now(session, alive_wildcard(run_id)))
    coords = sorted(live_coordinators(session, run_id))
    if robots or coords:
        who = ", ".join(([f"coordinator epoch {', '.join(map(str, coords))}"] if coords else [])
                        + ([f"agents of robots {', '.join(map(str, robots))}"] if robots else []))
        raise SwarmInputError(f"run {run_id} is live on this hub ({who}): a replay never publishes onto a live run; "
                              f"publish under a new run id (the default, or --run NEW)")


# ------------------------------------------------------------------ --check


def _overrides(args: argparse.Namespace) -> tuple[dict, dict]:
    model = load_model(args.model).to_dict() if args.model is not None else {}  # a model file replaces the recorded model
    model |= {field: convert(getattr(args, name)) for name, (field, convert) in MODEL_OPTIONS.items() if getattr(args, name) is not None}
    selection = {name: getattr(args, name) for name in SELECTION_OPTIONS if getattr(args, name) is not None}
    if "w_v" in selection and not 0.0 <= selection["w_v"] <= 1.0:
        raise SwarmInputError(f"--w-v must be in [0, 1], got {selection['w_v']}")
    return model, selection


def _recorded_selection_values(meta: dict) -> dict:
    """The selection options as the recording's metadata states them (only those it states)."""
    stored = meta.get("selection")
    if not isinstance(stored, dict):
        return {}
    genetic = stored.get("genetic") if isinstance(stored.get("genetic"), dict) else {}
    values = {"w_v": stored.get("w_v"), "samples": stored.get("samples"), "selection": stored.get("method"),
              "population": genetic.get("population"), "generations": genetic.get("generations")}
    return {k: v for k, v in values.items() if v is not None}


def contradictions(rec, args: argparse.Namespace, model: dict, selection: dict) -> list[str]:
    """The options given that differ from what the recording's metadata states, as ``--flag VALUE (recorded: X)``;
    model options equal to the recorded value up to rounding are removed from ``model`` (the recorded value is used)."""
    meta, found = rec.meta, []

    def differs(a, b) -> bool:
        if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
            return not math.isclose(float(a), float(b), rel_tol=1e-12, abs_tol=0.0)
        return a != b

    def note(dest: str, given, recorded, shown=None) -> None:
        if differs(given, recorded):
            shown_recorded = recorded if shown is None else shown
            typed = getattr(args, dest, None)
            flag = f"--{dest.replace('_', '-')} {typed}" if typed is not None else f"--model {args.model}: {dest} {shown_given(dest, given)}"
            found.append(f"{flag} (recorded: {shown_recorded})")

    def shown_given(dest: str, value) -> str:
        return f"{math.degrees(value):g}" if MODEL_OPTIONS.get(dest, (None, None))[1] is math.radians else f"{value:g}"

    if args.localizer is not None and "localizer" in meta:
        note("localizer", args.localizer, meta["localizer"])
    if args.seed is not None and "seed" in meta:
        note("seed", args.seed, meta["seed"])
    stored_model = meta.get("model") if isinstance(meta.get("model"), dict) else {}
    for dest, (field, convert) in MODEL_OPTIONS.items():
        if field in model and field in stored_model:
            recorded = float(stored_model[field])
            shown = f"{math.degrees(recorded):g}" if convert is math.radians else f"{recorded:g}"
            note(dest, model[field], recorded, shown)
            if not differs(model[field], recorded):  # the recorded value as typed (3 for 3.0000000000000004 deg): keep the exact one
                del model[field]
    for dest, recorded in _recorded_selection_values(meta).items():
        if dest in selection:
            note(dest, selection[dest], recorded)
    if args.trajectory is not None and isinstance(meta.get("trajectory"), dict):
        from runtime.models.trajectory import Trajectory  # noqa: PLC0415

        if Trajectory.load(args.trajectory).to_json() != meta["trajectory"]:
            found.append(f"--trajectory {args.trajectory} (the recording has another trajectory in its metadata)")
    return found


def run_check(args: argparse.Namespace) -> int:
    from coordinator.replay_check import check, load_recording  # noqa: PLC0415 - scipy when checking, not for --help

    model, selection = _overrides(args)
    rec = load_recording(args.file)
    if not rec.complete:
        print(f"swarm replay: {args.file} is unfinished ({rec.info['problem'] or 'no summary'}): checking what it holds",
              file=sys.stderr, flush=True)
    against = contradictions(rec, args, model, selection)
    if against and not args.what_if:
        raise SwarmInputError(
            f"{', '.join(against)} contradicts {args.file}: --check reproduces the recorded run with its own settings, so "
            f"leave these options out (they are for recordings whose metadata lacks them), or add --what-if to re-run "
            f"the recorded inputs with them (the check then reports where the results part)")
    if against:
        print(f"swarm replay: what-if: {', '.join(against)}: the recorded results are not expected to be reproduced",
              file=sys.stderr, flush=True)
    result = check(rec, localizer=args.localizer, model=model, selection=selection, seed=args.seed, trajectory=args.trajectory)
    s = result.settings
    print(f"checking {args.file}: method {s['method']}, {s['localizer']} localizer, seed {s['seed']}"
          + (f", overriding {', '.join(sorted({**model, **selection}))}" if model or selection else ""), flush=True)
    if not result.exact:
        from coordinator.replay_check import CROSS_PLATFORM_RTOL  # noqa: PLC0415
        print(f"recorded on another floating-point platform (or one the recording does not name): values are compared "
              f"to {CROSS_PLATFORM_RTOL:g} relative, not bit for bit", flush=True)
    for what in result.skipped:
        print(f"not checked: {what}", flush=True)
    if result.divergence is not None:
        if against:
            print(f"what-if ({', '.join(against)}): the results part from the recording", flush=True)
        print(f"check FAILED after {result.estimates} estimates and {result.plans} plans reproduced: {result.divergence}", flush=True)
    else:
        print(f"check passed: {result.estimates} estimates, {result.plans} plans reproduced", flush=True)
    if args.json:
        d = result.divergence
        print_json({"passed": result.passed, "exact": result.exact, "estimates": result.estimates, "plans": result.plans, "skipped": result.skipped,
                    "divergence": None if d is None else {"step": d.step, "what": d.what, "robot": d.robot, "field": d.field,
                                                          "recorded": d.recorded, "recomputed": d.recomputed}})
    return 0 if result.passed else EXIT_DIVERGED
