"""A lab's own driver (docs/drivers.md) under ``swarm launch`` (agent processes), faults included, and bad ``--driver`` values."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from inchworm.output import last_json
from runtime.recording.mcap_log import read_messages
from runtime.wire.messages import Status, decode
from swarm_cli.main import main

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = "examples/drivers/unicycle.py:UnicycleDriver"
FAULTS = "tests/fault_drivers.py"


def processes_of(run_id: str) -> list[int]:
    """Pids of processes whose command line names the run (none may outlive the launcher)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and int(entry.name) != os.getpid():
            try:
                if run_id.encode() in (entry / "cmdline").read_bytes():
                    pids.append(int(entry.name))
            except OSError:
                pass
    return pids


def launch(tmp_path: Path, run_id: str, *extra: str, timeout: float = 180) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "swarm_cli.main", "launch", "-n", "4", "--configs", "3", "--method", "no-anchors", "--run", run_id,
           "--record", str(tmp_path / "run.mcap"), "--out", str(tmp_path / "plots"), "--json", *extra]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=timeout)
    assert processes_of(run_id) == [], "a process of the run outlived swarm launch"
    return proc


def statuses(recording: Path, robot: int) -> list[Status]:
    return [decode(payload, Status) for topic, payload, _, _ in read_messages(recording) if topic.endswith(f"/robot/{robot}/status")]


def events(folder: Path, robot: int) -> list[str]:
    return [json.loads(line)["event"] for line in (folder / f"robot-{robot}.jsonl").read_text().splitlines()]


def test_the_example_driver_runs_a_launched_run(tmp_path):
    proc = launch(tmp_path, f"drv-ok-{os.getpid()}", "--driver", EXAMPLE, "--driver-option", "speed=2")
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = last_json(proc.stdout)
    assert result["lost"] == [] and result["finished_robots"] == 4 and 0 <= result["pf"] < 1


@pytest.mark.parametrize("cls, extra, reason, stopped_by", [
    ("RaisingDriver", (), "robot lost: driver error in execute: RuntimeError: motor controller fault", "estop"),
    ("HangingDriver", ("--command-timeout", "3"), "robot lost: the driver's execute did not return within 3 s", "estop"),
    ("LosingDriver", (), "robot lost: robot 1 stopped answering its radio", "stop"),
    # report_lost between steps (no command to refuse); motions take time, so steps remain after it
    ("LostWhileIdleDriver", ("--driver-option", "fail_step=1", "--driver-option", "speed=0.5"), None, "stop"),
])
def test_a_failing_driver_loses_its_robot_stopped_and_the_run_goes_on(tmp_path, cls, extra, reason, stopped_by):
    log = tmp_path / "log"
    log.mkdir()
    proc = launch(tmp_path, f"drv-{cls.lower()}-{os.getpid()}", "--driver", f"{FAULTS}:{cls}", "--driver-option", "fail_robot=1",
                  "--driver-option", "fail_step=2", "--driver-option", f"log={log}", *extra)
    assert proc.returncode == 0, proc.stderr[-2000:]  # --on-lost continue: the run ends normally without the robot
    result = last_json(proc.stdout)
    assert [lost["robot"] for lost in result["lost"]] == [1] and result["finished_robots"] == 3
    refusals = [status.reason for status in statuses(tmp_path / "run.mcap", 1) if status.state == "refused"]
    assert refusals == ([] if reason is None else [reason])  # what the agent said (the coordinator may see the token go first)
    assert result["lost"][0]["reason"] in (f"refused the command of step 2: {reason}", "liveliness token gone")
    seen = events(log, 1)
    assert seen.index("fault") < seen.index(stopped_by) and seen[-1] == "detach"  # stopped after the fault, then released
    assert "fault" not in events(log, 0) and events(log, 0)[-2:] == ["stop", "detach"]  # the others end normally


@pytest.mark.parametrize("spec, message", [
    ("no_such_package.driver:Robot", "no module named 'no_such_package.driver'"),
    ("robot_agent.driver:Nothing", "robot_agent.driver has no Nothing"),
    ("robot_agent.driver:PeerPoses", "is not a driver (a subclass of robot_agent.driver.Driver)"),
    ("robot_agent.driver:Driver", "Driver does not implement estop, execute, sense, stop"),
    ("missing/file.py:Robot", "no such file missing/file.py"),
    ("turtlebot", "not sim, gateway, ros2, package.module:Class, file.py:Class or an installed inchworm_swarm.drivers entry point"),
])
@pytest.mark.parametrize("command", ["agent", "launch"])
def test_a_bad_driver_is_one_line_and_exit_2(tmp_path, capsys, spec, message, command):
    args = (["agent", "--id", "0", "--ids", "0,1", "--run", "bad", "--hub", "tcp/127.0.0.1:9", "--pose", "0,0,0"] if command == "agent"
            else ["launch", "-n", "3", "--configs", "1", "--no-record", "--out", str(tmp_path)])
    assert main([*args, "--driver", spec]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"swarm {command}: error: --driver {spec}: {message}"] or (len(err) == 1 and message in err[0]), err


def test_an_installed_entry_point_names_a_driver(tmp_path, monkeypatch):
    """``--driver NAME`` finds the entry point NAME of the group ``inchworm_swarm.drivers`` of an installed package."""
    from robot_agent.plugins import ENTRY_POINT_GROUP, driver_class

    dist = tmp_path / "mylab_robots-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: mylab-robots\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\nunicycle = mylab_unicycle:UnicycleDriver\n")
    (tmp_path / "mylab_unicycle.py").write_text((REPO / "examples" / "drivers" / "unicycle.py").read_text())
    monkeypatch.syspath_prepend(str(tmp_path))
    cls = driver_class("unicycle")
    assert cls.__name__ == "UnicycleDriver" and cls.__module__ == "mylab_unicycle"


PACKAGE_DRIVER = '''
from robot_agent.plugins import driver_class

Unicycle = driver_class("{example}")


class BiasedDiffDrive(Unicycle):
    """The example robot, from a package in the working directory."""
'''


def test_a_package_in_the_working_directory_is_found_without_pythonpath(tmp_path):
    """``--driver mybot.diffdrive:Class`` from the folder holding ``mybot/``, by a ``swarm`` whose own folder is first on
    ``sys.path`` (``-P``: as the installed script starts); the kill-robot check right after the driver's ends it at once."""
    (tmp_path / "mybot").mkdir()
    (tmp_path / "mybot" / "__init__.py").write_text("")
    (tmp_path / "mybot" / "diffdrive.py").write_text(PACKAGE_DRIVER.format(example=REPO / EXAMPLE))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in [str(REPO), os.environ.get("PYTHONPATH", "")] if p)}
    proc = subprocess.run([sys.executable, "-P", "-m", "swarm_cli.main", "launch", "-n", "2", "--driver", "mybot.diffdrive:BiasedDiffDrive",
                           "--kill-robot", "9@1", "--no-record", "--out", str(tmp_path / "o")],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == ["swarm launch: error: --kill-robot 9@1: robot 9 is not one of the run's robots [0, 1]"]


def test_a_driver_whose_constructor_raises_ends_the_launch_in_one_line(tmp_path):
    """The agent of robot 1 cannot build its driver: the launch ends with that agent's error and exit 2 as soon as it exits,
    not after the coordinator's 30 s start timeout (the subprocess timeout would catch that wait)."""
    spec = f"{FAULTS}:FailingStartDriver"
    proc = launch(tmp_path, f"drv-start-{os.getpid()}", "--driver", spec, "--driver-option", "fail_robot=1", "--configs", "1",
                  timeout=25)
    assert proc.returncode == 2, proc.stderr
    errors = [line for line in proc.stderr.splitlines() if "error" in line]
    assert errors == [f"swarm launch: error: --driver {REPO / spec}: robot 1: the driver failed to start: RuntimeError: no robot 1 on /dev/ttyUSB1"]
    assert "not alive after" not in proc.stderr
