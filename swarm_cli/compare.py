"""``swarm compare``: Table I/II of the paper for every method on the same random trajectories (``inchworm.comparison``).

Runs are spread over the machine's cores; each finished run is kept at once in
``--out/runs.jsonl`` and ``--out/runs.csv``, so ``--resume`` continues an interrupted
comparison to the same result.
"""

from __future__ import annotations

import argparse

from inchworm.comparison import CompareOptions
from swarm_cli.options import add_simulation_options, add_study_options, run_options, run_study
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("compare", help="Table I/II: P_f of every method on the same random trajectories")
    add_fields(p, CompareOptions, exclude=("run",))
    add_study_options(p, "out/compare", "runs.jsonl, runs.csv, pf.png and study.toml")
    add_simulation_options(p)
    p.set_defaults(run=run)


def options(args: argparse.Namespace) -> CompareOptions:
    """The comparison the flags ask for."""
    return options_of(args, CompareOptions, run=run_options(args))


def run(args: argparse.Namespace) -> int:
    from inchworm.comparison import compare  # noqa: PLC0415

    chosen = options(args)
    return run_study(args, compare, chosen, len(chosen.tasks()), "compare")
