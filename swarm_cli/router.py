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
import resource
import signal
import sys
import threading

from runtime.errors import SwarmInputError
from swarm_cli.entry import run_standalone
from swarm_cli.options import print_json

DEFAULT_LISTEN = "tcp/0.0.0.0:7447"  # as runtime.wire.router
SAFE_OPEN_FILES = 65536  # a flood must not exhaust the router's files: one source address alone holds ~28,000 connections


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("router", help="run the Zenoh router of a multi-host swarm until Ctrl-C / SIGTERM")
    add_arguments(p)
    p.set_defaults(run=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help=f"endpoint to listen on, repeatable (default: the config file's, else {DEFAULT_LISTEN})")
    p.add_argument("--config", default=None, metavar="FILE",
                   help="Zenoh JSON5 config file, e.g. deploy/zenoh-router-tls-acl.json5 (TLS, access control)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout once listening")


def run(args: argparse.Namespace) -> int:
    from runtime.wire.router import router_settings  # noqa: PLC0415 - zenoh when it runs
    from runtime.wire.transport import open_session  # noqa: PLC0415

    settings = router_settings(args.listen, args.config)
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        try:
            session = open_session(settings)
        except ConnectionError as exc:
            raise SwarmInputError(f"cannot start the router on {', '.join(settings.listen)}: {exc.__cause__ or exc}") from None
        with session:
            source = f" (config {args.config})" if args.config else ""
            print(f"swarm router: listening on {', '.join(settings.listen)}{source}; zid {session.info.zid()}",
                  file=sys.stderr, flush=True)
            files = resource.getrlimit(resource.RLIMIT_NOFILE)[0]  # Zenoh raised the soft limit to the hard one
            if files < SAFE_OPEN_FILES:
                print(f"swarm router: warning: {files} open files allowed: a flood of that many connections blocks every listener, "
                      f"the stop path's too (raise the hard limit to {SAFE_OPEN_FILES}, e.g. LimitNOFILE= of its systemd unit; "
                      "deploy/README.md, \"The stop path\")", file=sys.stderr, flush=True)
            if args.json:
                print_json({"zid": str(session.info.zid()), "listen": list(settings.listen), "config": args.config})
            while not stop.wait(0.5):
                pass
    finally:
        for sig, handler in previous.items():  # matters when run in-process (tests)
            signal.signal(sig, handler)
    print("swarm router: stopped", file=sys.stderr, flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_standalone("swarm router", add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
