"""A launcher's children end with it, however it ends (SIGKILL included), and leave no folder behind.

The launcher (``Lifeline``) opens a pipe and keeps its only write end; every child it starts
gets the read end (``child_options``: ``pass_fds`` and two environment variables). A child
started through ``swarm_cli.entry.run_standalone`` calls ``hold_lifeline()`` first: on Linux
it asks the kernel for SIGTERM when its parent dies (``prctl(PR_SET_PDEATHSIG)``), and on
every system a thread blocks on the pipe, which reads end-of-file once the launcher is gone
(the kernel closes its write end even after SIGKILL), and sends the process SIGTERM. So each
child takes its own clean stop path (a coordinator publishes the run-wide stop and finishes
its recording) within milliseconds of the launcher's death.

The launcher's temporary folder is removed by a small guardian process
(``python -m inchworm.lifeline DIR``) that also holds the read end and removes the
folder when it reads end-of-file; it ignores the stop signals, which a terminal sends to the
whole process group, so it outlives the launcher by as long as the removal takes.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import shutil
import signal
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

FD_ENV = "SWARM_LIFELINE_FD"
PARENT_ENV = "SWARM_LIFELINE_PID"
PR_SET_PDEATHSIG = 1


class Lifeline:
    """The launcher's end: ``child_options()`` for every ``Popen``; ``close()`` when every child is stopped."""

    def __init__(self) -> None:
        self.read_fd, self._write_fd = os.pipe()  # both not inheritable (PEP 446): children get only read_fd
        self.guardian: subprocess.Popen[bytes] | None = None

    def child_options(self) -> dict[str, Any]:
        """``Popen`` keyword arguments that tie a child to this process."""
        env = {**os.environ, FD_ENV: str(self.read_fd), PARENT_ENV: str(os.getpid())}
        return {"pass_fds": (self.read_fd,), "env": env}

    def guard(self, folder: Path) -> None:
        """Start the guardian that removes ``folder`` once this process is gone."""
        self.guardian = subprocess.Popen([sys.executable, "-m", "inchworm.lifeline", str(folder)], **self.child_options())

    def close(self) -> None:
        """Let go of the children (they read end-of-file) and reap the guardian."""
        for fd in (self._write_fd, self.read_fd):
            try:
                os.close(fd)
            except OSError:
                pass
        if self.guardian is not None:
            try:
                self.guardian.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self.guardian.kill()
                self.guardian.wait()


def _die_with_parent() -> None:
    """Linux: SIGTERM from the kernel when the parent dies (a no-op elsewhere)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    except (OSError, AttributeError):
        pass


def _wait_for_eof(fd: int) -> None:
    try:
        while os.read(fd, 1):
            pass
    except OSError:
        pass


def hold_lifeline() -> None:
    """In a child of a launcher (``FD_ENV`` set): SIGTERM to this process as soon as the launcher is gone."""
    fd_text, parent = os.environ.pop(FD_ENV, None), os.environ.pop(PARENT_ENV, None)
    if fd_text is None:
        return
    _die_with_parent()
    if parent is not None and os.getppid() != int(parent):  # died before prctl took effect
        os.kill(os.getpid(), signal.SIGTERM)
    fd = int(fd_text)

    def watch() -> None:
        _wait_for_eof(fd)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="lifeline", daemon=True).start()


def main(argv: list[str] | None = None) -> int:
    """The guardian: wait for the launcher to be gone, then remove ``DIR``."""
    parser = argparse.ArgumentParser(prog="python -m inchworm.lifeline")
    parser.add_argument("remove", type=Path, metavar="DIR", help="folder to remove once the launcher is gone")
    args = parser.parse_args(argv)
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)
    fd = int(os.environ.pop(FD_ENV, "-1"))
    if fd < 0:
        parser.error("not started by a launcher (no lifeline)")
    _wait_for_eof(fd)
    shutil.rmtree(args.remove, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
