"""``swarm bench envelope``: replay, takeover, covariance honesty, contacts and speed across motion noise, swarm
size, localizer and sensing range (``inchworm.bench.envelope``; docs/benchmarks.md). ``--json``: the last line is
``{"trajectories", "configs", "distributed_configs", "rows": [{"noise_scale", "robots", "localizer", "sensing_range_m",
"replay_identical", "takeover_identical", "nees_median", "nees_p95", "contacts_per_100", "pf_mean", "s_per_config",
"steps_per_config"}, ...]}``."""

from __future__ import annotations

import argparse
import sys

from inchworm.bench.options import EnvelopeBenchOptions
from swarm_cli.options import add_json_option, add_workers_option, print_result
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("envelope", help="replay, takeover, NEES, contacts and speed across noise, size, localizer and sensing range")
    add_fields(p, EnvelopeBenchOptions, exclude=("workers",))
    add_workers_option(p)
    add_json_option(p)
    p.set_defaults(run=run)


def options(args: argparse.Namespace) -> EnvelopeBenchOptions:
    """The benchmark the flags ask for."""
    return options_of(args, EnvelopeBenchOptions, workers=args.workers)


def run(args: argparse.Namespace) -> int:
    from inchworm.bench.envelope import bench_envelope  # noqa: PLC0415

    result = bench_envelope(options(args), lambda text: print(f"bench envelope: {text}", file=sys.stderr, flush=True))
    return print_result(result, args.json)
