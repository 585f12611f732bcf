"""Processes started from specs: ``Spawned(spec)`` starts one, ``python -m inchworm.spawn`` is the child's entry point.

    proc = Spawned(AgentHostSpec(run_id="demo", robots=(0, 1), hub="tcp/127.0.0.1:7447", trajectory="traj.json"))
    ...
    proc.stop()          # SIGINT, then SIGTERM, then SIGKILL, each after a grace period; reaped

The child reads the spec (``inchworm.specs``) from its stdin (or a file: ``python -m inchworm.spawn SPEC.json``),
checks it (a bad spec: one line ``inchworm.spawn: error: ...`` on stderr, exit 2) and runs the function the
``swarm`` command of that kind runs (``inchworm.process_mains``), with that command's name in its messages and
its exit statuses. The process's last argument is the spec's kind (``agent``, ``port``, ``coordinator``,
``standby``, ...), so ``ps`` tells the processes apart. A child of a launcher ends with it (``inchworm.lifeline``).
"""

from __future__ import annotations

import importlib
import io
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

from inchworm.specs import ProcessSpec, SpecError, decode_spec, encode_spec, kind_of

PROG = "inchworm.spawn"
STOP_GRACE_S = 3.0  # s a child gets after each of SIGINT and SIGTERM
RUNNERS = {  # kind -> (the command it is, "module:function" that runs its spec)
    "agent": ("swarm agent", "inchworm.process_mains:run_agent_host"),
    "port": ("swarm agent", "inchworm.process_mains:run_agent_host"),
    "link": ("swarm link", "inchworm.process_mains:run_link"),
    "coordinator": ("swarm coordinator", "inchworm.process_mains:run_coordinator"),
    "emulator": ("swarm emulate-robots", "inchworm.process_mains:run_emulator"),
    "ros2-robots": ("swarm ros2 robots", "inchworm.process_mains:run_ros2_robots"),
    "ros2-bridge": ("swarm ros2 bridge", "inchworm.process_mains:run_ros2_bridge"),
    "router": ("swarm router", "inchworm.process_mains:run_router"),
    "recorder": ("swarm record", "inchworm.process_mains:run_recorder"),
    "launch": ("swarm launch", "inchworm.process_mains:run_launch"),
}


class Spawned(subprocess.Popen[Any]):  # its pipes carry text or bytes, as ``popen_kwargs`` ask
    """A child process running ``spec`` (a ``subprocess.Popen``: ``poll``, ``wait``, ``pid``, ``send_signal`` as usual);
    ``popen_kwargs`` as for ``Popen`` (``stdin`` is the spec's)."""

    def __init__(self, spec: ProcessSpec, **popen_kwargs: Any) -> None:
        self.spec = spec
        super().__init__([sys.executable, "-m", PROG, "-", spec.label], stdin=subprocess.PIPE, **popen_kwargs)
        data = encode_spec(spec)
        assert self.stdin is not None, "stdin is piped"
        try:
            self.stdin.write(data.decode() if isinstance(self.stdin, io.TextIOBase) else data)
            self.stdin.close()
        except BrokenPipeError:  # it died before reading: its status says so
            pass
        self.stdin = None  # the spec was all of it (``communicate`` then leaves stdin alone)

    def stop(self, grace_s: float = STOP_GRACE_S) -> int:
        """Stop it: SIGINT, SIGTERM after ``grace_s``, SIGKILL after another ``grace_s``; its exit status."""
        for sig in (signal.SIGINT, signal.SIGTERM):
            if self.poll() is not None:
                return self.returncode
            try:
                self.send_signal(sig)
                return self.wait(timeout=grace_s)
            except subprocess.TimeoutExpired:
                continue
        self.kill()
        return self.wait()


def run_process(spec: ProcessSpec, timeout: float | None = None, **popen_kwargs: Any) -> subprocess.CompletedProcess[str]:
    """Run ``spec`` to its end in a child, as ``subprocess.run`` with ``capture_output=True, text=True``; after ``timeout``
    seconds the child is stopped (``Spawned.stop``) and ``subprocess.TimeoutExpired`` raised."""
    with Spawned(spec, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **popen_kwargs) as proc:
        try:
            out, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.stop()
            raise
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def run_spec(spec: ProcessSpec) -> int:
    """Run ``spec`` in this process as its command would: its exit status (bad input: 2, its one line on stderr)."""
    from inchworm.entry import guarded  # noqa: PLC0415

    prog, target = RUNNERS[kind_of(spec)]
    module, _, function = target.partition(":")
    return guarded(prog, lambda: getattr(importlib.import_module(module), function)(spec))


def read_spec(source: str, label: str | None = None) -> ProcessSpec:
    """The spec in file ``source`` (``-``: stdin); ``label``: the kind it must be (``SpecError`` otherwise)."""
    try:
        data = sys.stdin.buffer.read() if source == "-" else Path(source).read_bytes()
    except OSError as exc:
        raise SpecError(f"cannot read the spec {source}: {exc.strerror or exc}") from None
    spec = decode_spec(data)
    if label is not None and label != spec.label:
        raise SpecError(f"the spec is a {spec.label} spec, not {label}")
    return spec


def main(argv: list[str] | None = None) -> int:
    """``python -m inchworm.spawn [SPEC|-] [KIND]``: run the spec (default stdin)."""
    from inchworm.entry import limit_blas_threads  # noqa: PLC0415
    from inchworm.lifeline import hold_lifeline  # noqa: PLC0415

    hold_lifeline()  # started by a launcher: end with it, whatever killed it
    limit_blas_threads()
    args = sys.argv[1:] if argv is None else argv
    if len(args) > 2 or any(a.startswith("-") and a != "-" for a in args):
        print(f"usage: python -m {PROG} [SPEC.json|-] [KIND]", file=sys.stderr)
        return 2
    try:
        spec = read_spec(args[0] if args else "-", args[1] if len(args) > 1 else None)
    except SpecError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr, flush=True)
        return 2
    return run_spec(spec)


if __name__ == "__main__":
    from inchworm.entry import leave

    leave(main())  # no interpreter finalization under Zenoh threads (inchworm.entry.leave)
