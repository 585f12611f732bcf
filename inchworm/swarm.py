"""A launched run as an object with a lifecycle: ``with inchworm.Swarm(options) as run: result = run.wait()``.

``Swarm(options)`` (``inchworm.launcher.LaunchOptions``) runs ``launcher.launch`` in a child process of its own
(``python -m inchworm.swarm``, tied to this process by ``inchworm.lifeline``: it ends with it, however this process
ends), so the launcher keeps its signal handling and this process stays free. The child gets the options as their
launch spec (``inchworm.specs.LaunchSpec``, every field: ``inchworm.process_mains.launch_spec``), the JSON that
``swarm launch`` runs too:

* ``start()`` (or entering ``with``) starts it; ``running()`` says whether it still runs.
* ``status()``: the run's live state, read from the run itself: its run file (the hub) and the liveliness tokens of
  its agents and coordinators on that hub (``SwarmStatus``).
* ``estop(reason)``: the run-wide emergency stop through the same path as ``swarm estop --run RUN``
  (``coordinator.node.stop.emergency_stop``); the agents' and links' acknowledgements come back (``EstopOutcome``).
* ``wait(timeout)`` returns the ``LaunchResult`` (status, recording, ``to_json()``: the keys of
  ``swarm launch --json``); ``result()`` the same once the run ended. A run that could not start raises the error
  the launcher gave (``SwarmInputError``, ``OptionError`` naming the parameter, ...).
* ``stop()`` (and leaving the ``with`` block before the run ended) stops it as Ctrl-C stops ``swarm launch``: the
  launcher publishes the run-wide stop, then stops every process it started; no process is left.

The run id is ``options.swarm.run_id`` or a fresh ``swarm-<hex>`` (``run_id``), so ``swarm estop --run`` and
``swarm record --run`` reach it from elsewhere too.
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import tempfile
import uuid
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

from inchworm.launcher import LaunchOptions, LaunchResult
from inchworm.lifeline import Lifeline
from inchworm.process_mains import launch_spec
from inchworm.specs import encode_spec
from runtime import errors
from runtime.errors import SwarmError, SwarmInputError

if TYPE_CHECKING:
    from coordinator.node.stop import EstopOutcome

SPEC_FILE = "launch.json"  # the child's launch spec, in its folder
STOP_GRACE_S = 60.0  # s the launcher gets to stop its run after SIGTERM (its coordinator alone may take 20 s to finish a recording)


@dataclass(frozen=True)
class SwarmStatus:
    """The live state of a run: ``state`` ``"starting"`` (no hub yet), ``"running"`` or ``"ended"``; its ``hub``, the
    robots whose agents are alive (``agents``), the coordinators alive (``coordinators``: epoch -> the epoch it took
    over, 0 for none) and, once ended, the launcher's exit ``status``."""

    run_id: str
    state: str
    hub: str | None = None
    agents: tuple[int, ...] = ()
    coordinators: dict[int, int] = dataclasses.field(default_factory=dict)
    status: int | None = None

    def to_json(self) -> dict[str, Any]:
        return {"run": self.run_id, "state": self.state, "hub": self.hub, "agents": list(self.agents),
                "coordinators": {str(k): v for k, v in self.coordinators.items()}, "status": self.status}


class Swarm:
    """A launched run (module doc)."""

    def __init__(self, options: LaunchOptions | None = None) -> None:
        options = options or LaunchOptions()
        run_id = options.swarm.run_id or f"swarm-{uuid.uuid4().hex[:10]}"
        self.options = dataclasses.replace(options, swarm=dataclasses.replace(options.swarm, run_id=run_id))
        self.run_id = run_id
        self._process: subprocess.Popen[bytes] | None = None
        self._lifeline: Lifeline | None = None
        self._folder: tempfile.TemporaryDirectory[str] | None = None
        self._result: LaunchResult | None = None

    def start(self) -> Swarm:
        """Start the launcher (once)."""
        if self._process is not None:
            raise SwarmInputError(f"run {self.run_id} was already started")
        self._folder = tempfile.TemporaryDirectory(prefix="inchworm-swarm-")
        folder = Path(self._folder.name)
        (folder / SPEC_FILE).write_bytes(encode_spec(launch_spec(self.options)))
        self._lifeline = Lifeline()
        self._process = subprocess.Popen([sys.executable, "-m", "inchworm.swarm", str(folder)], **self._lifeline.child_options())
        return self

    def running(self) -> bool:
        return self._process is not None and self._process.poll() is None

    def status(self) -> SwarmStatus:
        """The run's live state (``SwarmStatus``): its run file and, on its hub, its agents' and coordinators' tokens."""
        from coordinator.node.zenoh_backend import live_run  # noqa: PLC0415 - zenoh, only when asked
        from runtime.wire.run_file import read_run  # noqa: PLC0415
        from runtime.wire.transport import ZenohSettings, open_session  # noqa: PLC0415

        if self._process is None:
            return SwarmStatus(self.run_id, "starting")
        if not self.running():
            return SwarmStatus(self.run_id, "ended", status=self._process.returncode)
        entry = read_run(self.run_id)
        if entry is None:
            return SwarmStatus(self.run_id, "starting")
        with open_session(ZenohSettings("client", connect=(entry["hub"],))) as session:
            live = live_run(session, self.run_id, timeout_s=0.5)
        return SwarmStatus(self.run_id, "running", entry["hub"], tuple(sorted(live.robots)), live.coordinators)

    def estop(self, reason: str = "inchworm.Swarm.estop", ack_timeout_s: float = 1.0) -> EstopOutcome:
        """The run-wide emergency stop, as ``swarm estop --run RUN`` sends it; who acknowledged it."""
        from coordinator.node.stop import emergency_stop  # noqa: PLC0415 - zenoh, only when a stop is sent
        from runtime.wire.run_file import hub_of  # noqa: PLC0415
        from runtime.wire.transport import ZenohSettings  # noqa: PLC0415

        settings = ZenohSettings("client", connect=(hub_of(self.run_id),))
        return emergency_stop(settings, self.run_id, f"inchworm.Swarm (pid {os.getpid()})", reason, 0.0, ack_timeout_s)

    def wait(self, timeout: float | None = None) -> LaunchResult:
        """The run's ``LaunchResult`` once the launcher ended (``subprocess.TimeoutExpired`` after ``timeout`` s); raises
        the launcher's error if the run could not start."""
        if self._process is None:
            self.start()
        assert self._process is not None, "started above"
        self._process.wait(timeout)
        return self.result()

    def result(self) -> LaunchResult:
        """The ``LaunchResult`` of a run that ended (``SwarmInputError`` while it runs)."""
        if self._result is not None:
            return self._result
        if self._process is None or self._process.poll() is None:
            raise SwarmInputError(f"run {self.run_id} has not ended: wait() for it")
        assert self._folder is not None, "made by start()"
        answer = Path(self._folder.name) / "result.json"
        data = json.loads(answer.read_text(encoding="utf-8")) if answer.exists() else {}
        if "error" in data:
            raise _error(data["error"])
        status = data.get("status", self._process.returncode)
        self._result = LaunchResult(int(status if status is not None else -1), self.run_id,
                                    None if data.get("recording") is None else Path(data["recording"]), data.get("summary"))
        self._close()
        return self._result

    def stop(self, timeout: float = STOP_GRACE_S) -> LaunchResult | None:
        """Stop the run as Ctrl-C stops ``swarm launch`` (run-wide stop, every process stopped) and wait for it; its
        result, None if it never started. SIGKILL after ``timeout`` s (the lifeline then ends every child)."""
        if self._process is None:
            return None
        if self._process.poll() is None:
            self._process.send_signal(signal.SIGTERM)
            try:
                self._process.wait(timeout)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
        return self.result()

    def _close(self) -> None:
        if self._lifeline is not None:
            self._lifeline.close()
            self._lifeline = None
        if self._folder is not None:
            self._folder.cleanup()
            self._folder = None

    def __enter__(self) -> Swarm:
        return self.start()

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None, tb: TracebackType | None) -> None:
        try:
            if self.running():
                self.stop()
            elif self._process is not None and self._result is None and kind is None:
                self.result()  # an error the launcher gave is raised
        finally:
            self._close()


def _error(data: dict[str, Any]) -> SwarmError:
    """The launcher's error, rebuilt from what the child process wrote (its class if it is one of ``runtime.errors``)."""
    if data.get("parameter") is not None:
        return errors.OptionError(data["parameter"], data["problem"])
    kind = getattr(errors, str(data.get("kind")), None)
    simple = isinstance(kind, type) and issubclass(kind, SwarmError) and kind not in (errors.LocalizationError, errors.SwarmRunError)
    return kind(data["message"]) if simple else errors.SwarmRunError(data["message"])  # type: ignore[misc]  # checked just above


def _child(folder: Path) -> int:
    """The launcher's process: run ``launch`` on the options of the launch spec in ``folder`` and write its result (or
    error) there as JSON."""
    from inchworm.launcher import launch  # noqa: PLC0415
    from inchworm.lifeline import hold_lifeline  # noqa: PLC0415
    from inchworm.process_mains import launch_options  # noqa: PLC0415
    from inchworm.spawn import read_spec  # noqa: PLC0415
    from inchworm.specs import LaunchSpec  # noqa: PLC0415

    hold_lifeline()
    answer: dict[str, Any]
    try:
        spec = read_spec(str(folder / SPEC_FILE), "launch")
        assert isinstance(spec, LaunchSpec), "read_spec checked its kind"
        result = launch(launch_options(spec), capture=True)
        answer = {"status": result.status, "recording": None if result.recording is None else str(result.recording),
                  "summary": result.summary}
    except SwarmError as exc:
        answer = {"error": {"kind": type(exc).__name__, "message": str(exc), "parameter": getattr(exc, "parameter", None),
                            "problem": getattr(exc, "problem", None)}}
    except KeyboardInterrupt as exc:  # stopped (Swarm.stop, a signal): the launcher stopped the run and every child
        answer = {"status": 128 + getattr(exc, "signum", signal.SIGINT)}
    (folder / "result.json").write_text(json.dumps(answer), encoding="utf-8")
    return int(answer.get("status", 2))


if __name__ == "__main__":
    sys.exit(_child(Path(sys.argv[1])))
