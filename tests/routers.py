"""``swarm router`` processes on free loopback ports, for tests that run the router as its own process."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Mapping

from runtime.errors import SwarmConnectionError
from runtime.wire.transport import start_on_free_port


def start_router(procs: list[subprocess.Popen], env: Mapping[str, str] | None = None) -> str:
    """The endpoint of a ``swarm router`` listening on a free loopback port (appended to ``procs``; its stderr a pipe).
    A port another process took between its pick and the router's bind is replaced by a fresh one (the router's
    first line says it could not listen)."""
    def start(port: int) -> str:
        endpoint = f"tcp/127.0.0.1:{port}"
        router = subprocess.Popen([sys.executable, "-m", "swarm_cli.router", f"--listen={endpoint}"], env=env,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        assert router.stderr is not None
        line = router.stderr.readline()
        if "listening" not in line:
            router.wait(timeout=30)
            raise SwarmConnectionError(line.strip() or f"swarm router exited {router.returncode}")
        procs.append(router)
        return endpoint
    return start_on_free_port(start)[0]
