"""``swarm localize FILE.json``: run a localizer on a user's own data (``inchworm.localize_data``; format: docs/localize-input.md).

Robots that cannot be localized are left out and listed under ``excluded`` unless
``--strict``. When the solver fails (no convergence, singular information) for some or
all robots, the exit code is ``EXIT_NOT_LOCALIZED``: see docs/localize-input.md.
The checks of the rows (duplicates, ranges beyond the sensing range, suspects) are
warned on stderr, one line each, and listed in the JSON document.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from runtime.errors import LocalizationError
from swarm_cli.options import add_localizer_option, add_model_options, model_config, print_json
from swarm_cli.schema import add_fields, options_of

if TYPE_CHECKING:
    from inchworm.localize_data import LocalizeOptions

EXIT_NOT_LOCALIZED = 3  # the solver failed for some or all robots (bad input is 2)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from inchworm.localize_data import LocalizeOptions  # noqa: PLC0415 - numpy, as --localizer's registry

    p = sub.add_parser("localize", help="localize robots from range/bearing observations in a JSON file")
    p.add_argument("file", type=Path, help="input JSON (see docs/localize-input.md)")
    add_localizer_option(p)
    add_fields(p, LocalizeOptions, exclude=("source", "model", "localizer"))
    p.add_argument("--json", action="store_true", help="accepted for uniformity: the output is always one JSON object")
    add_model_options(p)
    p.set_defaults(run=run)


def options(args: argparse.Namespace) -> LocalizeOptions:
    """The ``LocalizeOptions`` of the flags: the file positional, the model group's model, ``--localizer``."""
    from inchworm.localize_data import LocalizeOptions  # noqa: PLC0415

    return options_of(args, LocalizeOptions, source=args.file, model=model_config(args), localizer=args.localizer)


def run(args: argparse.Namespace) -> int:
    from coordinator.localization.partial import SOLVER_FAILURES  # noqa: PLC0415
    from inchworm.localize_data import localize  # noqa: PLC0415

    try:
        result = localize(options(args))
    except LocalizationError as exc:
        if exc.reason not in SOLVER_FAILURES:
            raise  # unobserved / disconnected under --strict: an input problem (exit 2)
        print(f"swarm localize: error: {exc}", file=sys.stderr)
        return EXIT_NOT_LOCALIZED
    for robot, reason in sorted(result.excluded.items()):
        print(f"swarm localize: left out robot {robot}: {reason}", file=sys.stderr)
    for line in result.warnings:
        print(f"swarm localize: warning: {line}", file=sys.stderr)
    print_json(result.to_json())
    return EXIT_NOT_LOCALIZED if any(reason in SOLVER_FAILURES for reason in result.excluded.values()) else 0
