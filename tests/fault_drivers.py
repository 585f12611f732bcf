"""Drivers that fail, for tests/system/test_drivers.py: the example driver (examples/drivers/unicycle.py) plus one fault.

Selected with ``--driver tests/fault_drivers.py:Class`` and configured with ``--driver-option``:
``fail_robot`` (id), ``fail_step`` (the first step whose command fails) and ``log`` (a folder: each
driver appends its calls as JSON lines to ``<log>/robot-<id>.jsonl``, so a test sees that the robot
was stopped).
"""

from __future__ import annotations

import json
import threading
from pathlib import Path

from robot_agent.driver import RobotLost
from robot_agent.plugins import driver_class

UnicycleDriver = driver_class(f"{Path(__file__).resolve().parents[1] / 'examples' / 'drivers' / 'unicycle.py'}:UnicycleDriver")


class _Logged(UnicycleDriver):
    def __init__(self, ctx) -> None:
        super().__init__(ctx)
        self.fail_robot = int(ctx.options.get("fail_robot", -1))
        self.fail_step = int(ctx.options.get("fail_step", 1))
        folder = ctx.options.get("log")
        self.log_path = None if folder is None else Path(folder) / f"robot-{ctx.robot}.jsonl"

    def log(self, event: str, **fields) -> None:
        if self.log_path is not None:
            with open(self.log_path, "a", encoding="utf-8") as f:
                f.write(json.dumps({"robot": self.robot_id, "event": event, **fields}) + "\n")

    def failing(self, command) -> bool:
        return self.robot_id == self.fail_robot and command.step >= self.fail_step

    def execute(self, command):
        self.log("execute", step=command.step)
        if self.failing(command):
            self.log("fault", step=command.step)
            self.fail(command)
        return super().execute(command)

    def fail(self, command) -> None:
        raise NotImplementedError

    def estop(self, step: int = 0) -> None:
        self.log("estop", step=step)
        super().estop(step)

    def stop(self) -> None:
        self.log("stop")
        super().stop()

    def detach(self) -> None:
        self.log("detach")


class RaisingDriver(_Logged):
    """Its robot's motor controller throws at ``fail_step``."""

    def fail(self, command) -> None:
        raise RuntimeError("motor controller fault")


class HangingDriver(_Logged):
    """Its robot's call never returns at ``fail_step`` (a blocked serial read, a deadlock)."""

    def fail(self, command) -> None:
        threading.Event().wait()


class LosingDriver(_Logged):
    """Its robot stops answering at ``fail_step`` (the driver says so with ``RobotLost``)."""

    def fail(self, command) -> None:
        raise RobotLost(f"robot {self.robot_id} stopped answering its radio")


class LostWhileIdleDriver(_Logged):
    """Its robot's battery dies between steps: after sensing step ``fail_step`` the driver calls ``report_lost``."""

    def execute(self, command):
        self.log("execute", step=command.step)
        return UnicycleDriver.execute(self, command)

    def sense(self, peers, step: int = 0):
        result = super().sense(peers, step)
        if self.robot_id == self.fail_robot and step == self.fail_step:
            self.log("fault", step=step)
            threading.Timer(0.05, self.report_lost, args=(f"robot {self.robot_id}: battery flat",)).start()
        return result


class FailingStartDriver(_Logged):
    """Its robot ``fail_robot`` cannot be opened: the constructor raises (a wrong port, a robot switched off)."""

    def __init__(self, ctx) -> None:
        super().__init__(ctx)
        if self.robot_id == self.fail_robot:
            raise RuntimeError(f"no robot {self.robot_id} on /dev/ttyUSB{self.robot_id}")
