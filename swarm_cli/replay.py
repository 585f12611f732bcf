"""``swarm replay``: publish a recording again, or check that the coordinator reproduces it.

    swarm replay FILE --publish [--speed X] [--hub tcp/127.0.0.1:PORT] [--wait S] [--run NEW | --same-run]
    swarm replay FILE --check [--localizer L] [model / selection options] [--seed N] [--trajectory FILE] [--what-if]

What each mode does, and what it refuses, is ``inchworm.replay``'s module doc. ``--publish``
prints where it publishes and, at the end, what it sent; ``--check`` prints ``check passed: N
estimates, M plans reproduced`` (exit 0) or the first divergence (exit 1). Files that are not
MCAP, damaged or cut inside the header: a message naming the file and the problem, exit 2.
Unfinished (killed) recordings are read up to their last complete chunk.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from inchworm.limits import MODEL_FLAGS
from inchworm.replay import CheckOptions, PublishOptions
from swarm_cli.options import add_json_option, add_localizer_option, add_model_options, add_selection_options, print_json
from swarm_cli.schema import add_fields, options_of

EXIT_DIVERGED = 1
MODEL_OPTIONS = tuple(MODEL_FLAGS)  # the model flags' dests
SELECTION_OPTIONS = ("w_v", "samples", "population", "generations", "selection", "mc_start", "mc_emax")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("replay", help="re-publish a recording on Zenoh (--publish) or check that it is reproduced (--check)")
    p.add_argument("file", type=Path, help="MCAP recording (swarm coordinator / swarm record)")
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument("--publish", action="store_true", help="publish every recorded message again with its timing")
    mode.add_argument("--check", action="store_true", help="re-run localization and anchor selection, compare bit for bit")
    g = p.add_argument_group("--publish")
    add_fields(g, PublishOptions, only=("speed", "hub", "wait"))
    add_fields(g.add_mutually_exclusive_group(), PublishOptions, only=("run_id", "same_run"))
    c = p.add_argument_group("--check (options given override the recorded ones)")
    add_fields(c, CheckOptions, only=("seed", "trajectory", "what_if"))
    add_localizer_option(p)
    add_selection_options(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run, localizer=None, **{name: None for name in (*MODEL_OPTIONS, *SELECTION_OPTIONS)})


def run(args: argparse.Namespace) -> int:
    return run_check(args) if args.check else run_publish(args)


def _say(text: str) -> None:
    print(text, flush=True)


def _warn(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def publish_options(args: argparse.Namespace) -> PublishOptions:
    """``--publish``'s options of the flags."""
    return options_of(args, PublishOptions, file=args.file)


def check_options(args: argparse.Namespace) -> CheckOptions:
    """``--check``'s options of the flags (None, the recorded value, for each flag not given)."""
    return options_of(args, CheckOptions, file=args.file, localizer=args.localizer, model_file=args.model,
                      model_flags={name: getattr(args, name) for name in MODEL_OPTIONS},
                      selection={name: getattr(args, name) for name in SELECTION_OPTIONS})


def run_publish(args: argparse.Namespace) -> int:
    from inchworm.replay import publish  # noqa: PLC0415 - zenoh only when publishing
    from runtime.wire.keys import ROOT  # noqa: PLC0415

    r = publish(publish_options(args), say=_say, warn=_warn)
    print(f"replayed {r.messages} messages on {r.keys} keys in {r.elapsed_s:.3f} s "
          f"(recorded span {r.recorded_s:.3f} s, speed {'max' if r.fast else f'{args.speed:g}'})"
          + (f"; {r.skipped} messages of derived channels (outside {ROOT}/) not published" if r.skipped else ""), flush=True)
    if args.json:
        print_json(r.to_json())
    return 0


def run_check(args: argparse.Namespace) -> int:
    from coordinator.replay_check import CROSS_PLATFORM_RTOL  # noqa: PLC0415 - scipy when checking, not for --help
    from inchworm.replay import check_recording  # noqa: PLC0415

    outcome = check_recording(check_options(args), warn=_warn)
    result, model, selection, against = outcome.result, outcome.model, outcome.selection, outcome.against_flags
    s = result.settings
    print(f"checking {args.file}: method {s['method']}, {s['localizer']} localizer, seed {s['seed']}"
          + (f", overriding {', '.join(sorted({**model, **selection}))}" if model or selection else ""), flush=True)
    if not result.exact:
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
        print_json(outcome.to_json())
    return 0 if result.passed else EXIT_DIVERGED
