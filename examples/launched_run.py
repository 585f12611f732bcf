"""A distributed run from Python as an object: agent processes and a coordinator on Zenoh over loopback.

    python examples/launched_run.py [--robots N] [--configs K] [--motion-time S] [--estop-after S] [--out DIR]

``inchworm.Swarm`` starts what ``swarm launch`` starts; while it runs, ``status()`` reads the run's
live state (its agents' and coordinator's liveliness on the hub), ``estop()`` sends the emergency
stop ``swarm estop --run RUN`` sends, and ``wait()`` returns the ``LaunchResult`` (its ``to_json()``
is what ``swarm launch --json`` prints). Leaving the ``with`` block stops whatever still runs.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import inchworm
from inchworm import LaunchOptions, OutputOptions, SwarmOptions


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description="A launched run: status while it runs, then its result.")
    p.add_argument("--robots", type=int, default=6)
    p.add_argument("--configs", type=int, default=2)
    p.add_argument("--motion-time", type=float, default=0.2, help="seconds a simulated motion takes (default 0.2)")
    p.add_argument("--estop-after", type=float, default=None, metavar="S", help="send the emergency stop S seconds after the agents are up")
    p.add_argument("--out", default="out/launched_run", help="folder for the plots and the recording")
    args = p.parse_args(argv)

    options = LaunchOptions(swarm=SwarmOptions(robots=args.robots, configs=args.configs, motion_time=args.motion_time),
                            outputs=OutputOptions(out=args.out, record=f"{args.out}/run.mcap"))
    try:
        with inchworm.Swarm(options) as run:
            while len((status := run.status()).agents) < args.robots and status.state != "ended":
                time.sleep(0.2)
            print(f"run {run.run_id} on {status.hub}: agents {list(status.agents)} alive, coordinators {status.coordinators}")
            if args.estop_after is not None:
                time.sleep(args.estop_after)
                print(f"emergency stop acknowledged by robots {run.estop('examples/launched_run.py').agents}")
            result = run.wait()
    except inchworm.SwarmInputError as exc:
        print(f"launched_run.py: error: {exc}", file=sys.stderr)
        return 2
    print(f"status {result.status}, P_f {result.pf}, lost robots {result.lost}, recording {result.recording}")
    print(json.dumps(result.to_json()))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
