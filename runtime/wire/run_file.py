"""Run files: where a live run's hub is, so that ``swarm estop --run RUN`` (and every command with
``--run`` and no ``--hub``) finds it without copying an address.

While a ``swarm launch`` / ``swarm demo`` (or a ``swarm replay --publish`` on its own hub) runs,
it keeps ``<run dir>/<run>.json``::

    {"run": "launch-4242", "hub": "tcp/127.0.0.1:40123", "pid": 4242, "command": "swarm demo", "started_unix": 1764111111.5}

and removes it when it exits (also on error or Ctrl-C; a SIGKILLed launcher leaves a stale
file, which readers recognise by its dead pid and remove). The run directory is
``$SWARM_RUN_DIR`` if set, else ``$XDG_RUNTIME_DIR/inchworm-swarm``, else
``<temp dir>/inchworm-swarm-<uid>``; it is created private (mode 0700). Only processes of this
host see it: for multi-host runs give ``--hub`` (deploy/README.md).
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from runtime.errors import OptionError
from runtime.wire.keys import validate_run

ENV_DIR = "SWARM_RUN_DIR"
RUN_FLAG = {"run_id": "--run"}  # the flag of a run id (``OptionError``'s options)


def run_dir() -> Path:
    """The folder of the run files (module doc)."""
    if os.environ.get(ENV_DIR):
        return Path(os.environ[ENV_DIR])
    if os.environ.get("XDG_RUNTIME_DIR"):
        return Path(os.environ["XDG_RUNTIME_DIR"]) / "inchworm-swarm"
    return Path(tempfile.gettempdir()) / f"inchworm-swarm-{os.getuid()}"


def run_file(run_id: str) -> Path:
    return run_dir() / f"{validate_run(run_id)}.json"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def read_run(run_id: str) -> dict[str, Any] | None:
    """The run file of ``run_id`` if its process is alive; None if there is none (a stale one is removed)."""
    path = run_file(run_id)
    try:
        entry = json.loads(path.read_text())
        pid, hub = int(entry["pid"]), str(entry["hub"])
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, TypeError):
        raise OptionError("run_id", f"{run_id}: its run file {path} is unreadable: remove it, or give `hub`", RUN_FLAG) from None
    if not _alive(pid):
        with contextlib.suppress(OSError):
            path.unlink()
        return None
    return {**entry, "pid": pid, "hub": hub, "path": str(path)}


def hub_of(run_id: str) -> str:
    """The hub of live run ``run_id`` from its run file; ``SwarmInputError`` saying what to do if there is none."""
    entry = read_run(run_id)
    if entry is None:
        raise OptionError("run_id", f"{run_id}: no live run of that id on this host (no run file {run_file(run_id)}): "
                                    f"give `hub` ENDPOINT (e.g. tcp/127.0.0.1:7447) or `zenoh_config` FILE", RUN_FLAG)
    return str(entry["hub"])  # a str: read_run made it one


@contextlib.contextmanager
def published_run(run_id: str, hub: str, command: str) -> Iterator[Path]:
    """Keep the run file of ``run_id`` (this process, ``hub``) while the block runs; refuse a run id already live."""
    other = read_run(run_id)
    if other is not None:
        raise OptionError("run_id", f"{run_id}: that run is already live on this host (pid {other['pid']}, hub {other['hub']}, "
                                    f"{other['path']}): choose another run id", RUN_FLAG)
    path = run_file(run_id)
    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}")
    tmp.write_text(json.dumps({"run": run_id, "hub": hub, "pid": os.getpid(), "command": command, "started_unix": time.time()}))
    os.replace(tmp, path)
    try:
        yield path
    finally:
        with contextlib.suppress(OSError, ValueError, KeyError, TypeError):
            if int(json.loads(path.read_text())["pid"]) == os.getpid():
                path.unlink()
