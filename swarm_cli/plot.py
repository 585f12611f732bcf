"""``swarm plot``: the plots of ``swarm sim`` (Fig. 13/14 trajectory, Fig. 17 errors) from a recording.

    swarm plot recordings/demo.mcap [--out DIR] [--trajectory FILE]

The run is rebuilt from the recording (``coordinator.replay_check.rebuild_run``): the
initial estimate (EstimateMessage of step 0), per configuration its plan (PlanMessage) and
the estimate after its last step (the plan's first step + its number of steps - 1), the
truth from TruthMessages (simulated runs), the desired configurations from the trajectory in
the run metadata (or ``--trajectory``). An unfinished recording is plotted up to its last
completed configuration. Writes ``trajectory.png`` and, with ground truth, ``errors.png``
to ``--out`` (default ``out/plot``). Unreadable files: a message, exit 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from swarm_cli.options import add_json_option, print_json


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("plot", help="the trajectory and error plots of swarm sim, from a recording")
    p.add_argument("file", type=Path, help="MCAP recording (swarm coordinator / swarm record)")
    p.add_argument("--out", type=Path, default=Path("out/plot"), help="folder for the PNG plots (default out/plot)")
    p.add_argument("--trajectory", type=Path, default=None, help="trajectory JSON, if the recording has none in its metadata")
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from coordinator.replay_check import load_recording, rebuild_run  # noqa: PLC0415 - scipy and matplotlib when it runs
    from inchworm.plots import write_run_plots  # noqa: PLC0415

    rec = load_recording(args.file)
    if not rec.complete:
        print(f"swarm plot: {args.file} is unfinished ({rec.info['problem'] or 'no summary'}): plotting what it holds",
              file=sys.stderr, flush=True)
    result = rebuild_run(rec, args.trajectory)
    plots = write_run_plots(result, args.out)
    k, total = len(result.configs), len(result.trajectory.configurations)
    pf = result.pf() if result.has_truth else None
    print(f"{result.method}: {k} of {total} configurations, {len(result.steps)} steps"
          + (f", P_f = {pf:.4f}" if pf is not None else ", no ground truth") + f"; wrote {', '.join(plots)}", flush=True)
    if args.json:
        print_json({"method": result.method, "configs": k, "of": total, "steps": len(result.steps), "pf": pf, "plots": plots})
    return 0
