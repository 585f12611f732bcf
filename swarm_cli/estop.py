"""``swarm estop``: emergency stop of every robot of a run.

    swarm estop --run lab [--hub tcp/127.0.0.1:7447] [--reason "..."]

Without ``--hub`` / ``--zenoh-config`` the hub is the one of the live run ``--run`` names on
this host, from the run file its launcher keeps (``runtime.wire.run_file``).

Publishes one ``EmergencyStop`` on ``swarm/<run>/estop``, a few times over ``--repeat-s``
(default 0.3 s) so that it also reaches subscribers whose route is still being set up.
Every agent forwards it to its robot at once and refuses later commands; every link
process sends ESTOP to all robots of its port, which stay stopped until reset.
"""

from __future__ import annotations

import argparse
import os
import sys

from coordinator.stop import send_estop
from runtime.wire.keys import validate_run
from runtime.wire.transport import open_session
from swarm_cli.options import add_connection_options, add_json_option, connection_label, connection_settings, print_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("estop", help="emergency stop: every robot of the run stops now (latched)")
    p.add_argument("--run", dest="run_id", required=True, help="run id (the key space swarm/<run>/...)")
    p.add_argument("--reason", default="operator", help="why, for the logs (default operator)")
    p.add_argument("--repeat-s", type=float, default=0.3, help="publish again over this many seconds (default 0.3)")
    add_connection_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    validate_run(args.run_id)
    with open_session(connection_settings(args)) as session:
        sent = send_estop(session, args.run_id, f"swarm estop (pid {os.getpid()})", args.reason, args.repeat_s)
    print(f"swarm estop: emergency stop sent to run {args.run_id} on {connection_label(args)}", file=sys.stderr, flush=True)
    if args.json:
        print_json({"run": args.run_id, "published": sent})
    return 0
