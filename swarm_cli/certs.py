"""``swarm certs``: a lab certificate authority and one TLS certificate per host, for mutual TLS (``inchworm.certs``).

    swarm certs --out certs/ [--host router=192.168.1.10,coordinator-pc.local] [--host gateway=10.0.0.7] ...

Writes ``ca.pem`` / ``ca.key`` (reused when ``--out`` has them) and ``<name>.pem`` /
``<name>.key`` per ``--host`` (default hosts: router, coordinator, gateway, estop) into ``--out``;
see ``inchworm.certs`` for the certificates' contents. Prints one line per file written;
``--json`` adds one JSON object as the last line: ``{"out": DIR, "ca": {"cert", "key",
"reused"}, "hosts": {name: {"cert", "key", "sans"}}}``. Exit status 0, 2 on bad input
(bad names, missing openssl, unwritable directory).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from swarm_cli.entry import run_standalone
from swarm_cli.options import print_json

DEFAULT_HOSTS = ("router", "coordinator", "gateway", "estop")  # as inchworm.certs


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("certs", help="create a lab CA and per-host TLS certificates (mutual TLS, see deploy/README.md)")
    add_arguments(p)
    p.set_defaults(run=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, required=True, help="directory for ca.pem/ca.key and <name>.pem/<name>.key")
    p.add_argument("--host", action="append", default=None, metavar="NAME[=SAN,...]",
                   help="a certificate with CN NAME and extra subject alternative names (IP addresses or DNS names); "
                        f"repeatable (default: {', '.join(DEFAULT_HOSTS)})")
    p.add_argument("--days", type=int, default=825, help="validity of host certificates in days (default 825)")
    p.add_argument("--ca-days", type=int, default=3650, help="validity of a new CA in days (default 3650)")
    p.add_argument("--json", action="store_true", help="print one JSON object as the last line")


def run(args: argparse.Namespace) -> int:
    from inchworm.certs import make_certs, parse_host  # noqa: PLC0415

    result = make_certs(args.out, [parse_host(h) for h in (args.host or DEFAULT_HOSTS)], args.days, args.ca_days,
                        lambda line: print(line, flush=True))
    if args.json:
        print_json(result)
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_standalone("swarm certs", add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
