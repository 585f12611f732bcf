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

``swarm router: listening on ...`` on stderr means the session is open and listening;
``--json`` then prints ``{"zid": ..., "listen": [...], "config": ...}`` as the only (so also
the last) line on stdout. Exit status 0, 2 on bad input (bad endpoint, unreadable or
invalid config file, unreadable certificate, port already in use).
``python -m swarm_cli.router`` is the same command.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading

import zenoh

from runtime.errors import SwarmInputError
from runtime.wire.transport import ZenohSettings, open_session
from swarm_cli.entry import STOP_SIGNALS, run_standalone
from swarm_cli.options import print_json

DEFAULT_LISTEN = "tcp/0.0.0.0:7447"
TLS_FILE_FIELDS = (
    "root_ca_certificate",
    "listen_certificate",
    "listen_private_key",
    "connect_certificate",
    "connect_private_key",
)


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


def _file_endpoints(config: zenoh.Config) -> list[str]:
    """The listen endpoints a config file gives a router (the field may be per mode)."""
    value = json.loads(config.get_json("listen/endpoints"))
    if isinstance(value, dict):
        value = value.get("router", [])
    return list(value or [])


def check_tls_files(config: zenoh.Config, source: str) -> None:
    """``SwarmInputError`` naming the field if a certificate or key path of ``transport/link/tls`` is unreadable."""
    tls = json.loads(config.get_json("transport/link/tls"))
    for field in TLS_FILE_FIELDS:
        path = tls.get(field)
        if path is None:
            continue
        if not isinstance(path, str) or not os.path.isfile(path) or not os.access(path, os.R_OK):
            raise SwarmInputError(f"{source}: transport/link/tls/{field} {path!r} is not a readable file")


def router_settings(listen: list[str], config_file: str | None) -> ZenohSettings:
    """The router's ``ZenohSettings``: checks the file, its TLS paths and the endpoints (no port 0)."""
    endpoints = tuple(listen)
    if config_file is not None:
        if not os.path.isfile(config_file) or not os.access(config_file, os.R_OK):
            raise SwarmInputError(f"--config {config_file!r} is not a readable file")
        config = ZenohSettings("router", config_file=config_file).to_config()  # SwarmInputError if invalid
        check_tls_files(config, f"--config {config_file}")
        if not endpoints:
            endpoints = tuple(_file_endpoints(config))
    settings = ZenohSettings("router", listen=endpoints or (DEFAULT_LISTEN,), config_file=config_file)
    for endpoint in settings.listen:
        if endpoint.split("?")[0].split("#")[0].endswith(":0"):
            raise SwarmInputError(f"listen endpoint {endpoint!r}: give a fixed port (clients must know it)")
    return settings


def run(args: argparse.Namespace) -> int:
    settings = router_settings(args.listen, args.config)
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in STOP_SIGNALS}
    try:
        try:
            session = open_session(settings)
        except ConnectionError as exc:
            raise SwarmInputError(f"cannot start the router on {', '.join(settings.listen)}: {exc.__cause__ or exc}") from None
        with session:
            source = f" (config {args.config})" if args.config else ""
            print(f"swarm router: listening on {', '.join(settings.listen)}{source}; zid {session.info.zid()}",
                  file=sys.stderr, flush=True)
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
