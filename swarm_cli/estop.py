"""``swarm estop``: emergency stop of every robot of a run.

    swarm estop --run lab [--hub tcp/127.0.0.1:7447] [--reason "..."] [--ack-timeout 1] [--json]

Without ``--hub`` / ``--zenoh-config`` the hub is the one of the live run ``--run`` names on
this host, from the run file its launcher keeps (``runtime.wire.run_file``).

Publishes one ``EmergencyStop`` on ``swarm/<run>/estop``, a few times over ``--repeat-s``
(default 0.3 s) so that it also reaches subscribers whose route is still being set up.
Every agent forwards it to its robot at once and refuses later commands; every link
process sends ESTOP to all robots of its port, which stay stopped until reset. Each of
them acknowledges it with an ``EstopAck`` on ``swarm/<run>/estop/ack``; ``swarm estop``
collects them for ``--ack-timeout`` seconds (default 1) after the first publication and
says who acknowledged: ``emergency stop of run lab acknowledged by 10 agents (robots
0-9) and 2 links (ports radio0, radio1)``.

On a lab's TLS router (deploy/), stop from the router's PC with ``--zenoh-config
/etc/swarm/zenoh-estop-tls.json5``: the estop identity through the router's operator listener,
which a connection flood of its public listener does not hold up (deploy/README.md, "The stop
path"; ``swarm bench faults``, ``estop_under_flood``).

Exit status: 0 when at least one agent or link acknowledged, 1 when none did (a wrong
``--run`` or hub, or nobody listening: the stop reached no robot that can be named), 2 on
bad input. ``--json`` prints ``{"run", "published", "agents", "links", "robots"}`` last
(``agents``: robot ids of the agents that acknowledged, ``links``: port names,
``robots``: every robot an agent or link said it stopped).
"""

from __future__ import annotations

import argparse
import os
import sys

from swarm_cli.options import add_connection_options, add_json_option, connection_label, connection_settings, print_json

EXIT_NO_ACK = 1


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("estop", help="emergency stop: every robot of the run stops now (latched)")
    p.add_argument("--run", dest="run_id", required=True, help="run id (the key space swarm/<run>/...)")
    p.add_argument("--reason", default="operator", help="why, for the logs (default operator)")
    p.add_argument("--repeat-s", type=float, default=0.3, help="publish again over this many seconds (default 0.3)")
    p.add_argument("--ack-timeout", type=float, default=1.0,
                   help="seconds to collect the acknowledgements of agents and links (default 1)")
    add_connection_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from coordinator.node.stop import emergency_stop  # noqa: PLC0415 - zenoh, only when a command runs

    settings = connection_settings(args)
    assert settings is not None, "add_connection_options(p): required"
    out = emergency_stop(settings, args.run_id, f"swarm estop (pid {os.getpid()})", args.reason, args.repeat_s, args.ack_timeout)
    robots, ports = ", ".join(map(str, out.agents)), ", ".join(out.links)
    if out.agents or out.links:
        print(f"swarm estop: emergency stop of run {args.run_id} on {connection_label(args)} acknowledged by {len(out.agents)} agents"
              f"{f' (robots {robots})' if robots else ''} and {len(out.links)} links{f' (ports {ports})' if ports else ''}",
              file=sys.stderr, flush=True)
    else:
        print(f"swarm estop: emergency stop published to run {args.run_id}, but no agent or link acknowledged it "
              f"within {args.ack_timeout:g} s: is the run id right and the run on this hub?", file=sys.stderr, flush=True)
    if args.json:
        print_json(out.to_json())
    return 0 if out.agents or out.links else EXIT_NO_ACK
