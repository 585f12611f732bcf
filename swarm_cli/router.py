"""``swarm router``: the Zenoh router of a multi-host swarm, as a Python session (no ``zenohd`` needed).

    swarm router [--listen tcp/0.0.0.0:7447 ...] [--config deploy/zenoh-router-tls-acl.json5] [--json]

Opens a Zenoh session in ``router`` mode (multicast scouting off) and keeps it open until
SIGTERM or SIGINT, then closes it and exits 0. The coordinator, gateway processes and
tools connect to it as clients (``--hub`` / ``--zenoh-config``; see ``deploy/README.md``).

* ``--config FILE``: a Zenoh JSON5 file, e.g. ``deploy/zenoh-router-tls-acl.json5``
  (mutual TLS and access control). Its mode is forced to ``router``; every file path in
  its ``transport/link/tls`` section must be a readable file.
* ``--listen ENDPOINT`` (repeatable): where to listen, e.g. ``tcp/0.0.0.0:7447`` or
  ``tls/192.168.1.10:7447``; overrides the file's endpoints. Default: the file's
  endpoints, else ``tcp/0.0.0.0:7447``. Port 0 is refused (clients could not know it).

``swarm router: listening on ...`` on stderr means the session is open and listening; a warning
follows when the process may open fewer than 65536 files (Zenoh raises the soft limit to the hard
one): a connection flood that exhausts them blocks every listener, the operator listener of the
stop path too (deploy/README.md, "The stop path").
``--json`` then prints ``{"zid": ..., "listen": [...], "config": ...}`` as the only (so also
the last) line on stdout. Exit status 0, 2 on bad input (bad endpoint, unreadable or
invalid config file, unreadable certificate, port already in use).
``python -m swarm_cli.router`` is the same command.
"""

from __future__ import annotations

import argparse
import sys

from inchworm.specs import RouterSpec
from swarm_cli.entry import run_standalone
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("router", help="run the Zenoh router of a multi-host swarm until Ctrl-C / SIGTERM")
    add_arguments(p)
    p.set_defaults(run=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_fields(p, RouterSpec)  # every flag is a field of the spec


def run(args: argparse.Namespace) -> int:
    from inchworm.process_mains import run_router  # noqa: PLC0415 - zenoh when it runs

    return run_router(spec_of(args))


def spec_of(args: argparse.Namespace) -> RouterSpec:
    """The router spec of the flags."""
    return options_of(args, RouterSpec)


def main(argv: list[str] | None = None) -> int:
    return run_standalone("swarm router", add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
