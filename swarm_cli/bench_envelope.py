"""``swarm bench envelope``: replay, takeover, covariance honesty, contacts and speed across motion noise, swarm
size, localizer and sensing range (``inchworm.bench.envelope``; docs/benchmarks.md). ``--json``: the last line is
``{"trajectories", "configs", "distributed_configs", "rows": [{"noise_scale", "robots", "localizer", "sensing_range_m",
"replay_identical", "takeover_identical", "nees_median", "nees_p95", "contacts_per_100", "pf_mean", "s_per_config",
"steps_per_config"}, ...]}``."""

from __future__ import annotations

import argparse
import sys

from swarm_cli.options import add_json_option, add_workers_option, print_result


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def _ints(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("envelope", help="replay, takeover, NEES, contacts and speed across noise, size, localizer and sensing range")
    p.add_argument("--noise-scales", type=_floats, default=(1.0, 3.0, 5.58), help="motion noise multiples (default 1,3,5.58)")
    p.add_argument("--robots", type=_ints, default=(10, 30), help="swarm sizes (default 10,30)")
    p.add_argument("--localizers", default="paper,joint", help="comma-separated localizers (default paper,joint)")
    p.add_argument("--sensing-ranges", type=_floats, default=(0.5, 3.0), help="sensing ranges in m (default 0.5,3)")
    p.add_argument("--trajectories", type=int, default=4, help="in-process runs per row (default 4)")
    p.add_argument("--configs", type=int, default=8, help="configurations per in-process run (default 8)")
    p.add_argument("--distributed-configs", type=int, default=3, help="configurations of each row's distributed run (default 3)")
    p.add_argument("--no-distributed", action="store_true", help="in-process rows only (replay and takeover not measured)")
    p.add_argument("--seed", type=int, default=0, help="trajectory t uses seed + t (default 0)")
    add_workers_option(p)
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from inchworm.bench.envelope import EnvelopeBenchOptions, bench_envelope  # noqa: PLC0415
    from swarm_cli.options import names  # noqa: PLC0415

    options = EnvelopeBenchOptions(noise_scales=args.noise_scales, robots=args.robots, localizers=names(args.localizers),
                                   sensing_ranges_m=args.sensing_ranges, trajectories=args.trajectories, configs=args.configs,
                                   distributed_configs=args.distributed_configs, distributed=not args.no_distributed,
                                   seed=args.seed, workers=args.workers)
    result = bench_envelope(options, lambda text: print(f"bench envelope: {text}", file=sys.stderr, flush=True))
    return print_result(result, args.json)
