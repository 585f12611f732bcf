"""The gateway config file (runtime/gateway/config.py), calibration maths, the ANT device string, limits."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

from robot_agent.ant_link import AntLink, parse_ant_device
from runtime.errors import SwarmInputError
from runtime.gateway.config import Calibration, GatewayConfig
from runtime.wire.messages import CommandLimits, MotionCommand

EXAMPLE = Path(__file__).resolve().parents[2] / "deploy" / "gateway.example.json"


def test_example_config_loads_and_round_trips(tmp_path):
    config = GatewayConfig.load(EXAMPLE)
    assert config.robots == list(range(10))
    assert config.port_of(7).name == "radio1" and config.port("radio0").robots == (0, 1, 2, 3, 4)
    assert config.calibration_of(3).motion_scale == 0.96 and config.calibration_of(4) == Calibration()
    live = config.with_devices({"radio0": "/dev/pts/9"})
    assert live.port("radio0").device == "/dev/pts/9" and live.port("radio1").device == "/dev/ttyUSB1"
    live.save(tmp_path / "live.json")
    assert GatewayConfig.load(tmp_path / "live.json").to_json() == live.to_json()


def _base() -> dict:
    return {"ports": [{"name": "radio0", "device": "/dev/ttyUSB0", "robots": [0, 1]}]}


@pytest.mark.parametrize("change,message", [
    (lambda d: d.pop("ports"), "missing field(s) ['ports']"),
    (lambda d: d.update(ports=[]), "ports: must be a non-empty list"),
    (lambda d: d["ports"][0].update(name="bad/name"), "ports[0].name"),
    (lambda d: d["ports"][0].update(robots=[0, 0]), "lists a robot twice"),
    (lambda d: d["ports"][0].update(robots=[70000]), "ports[0].robots[0]: must be an integer in [0, 65534]"),
    (lambda d: d["ports"].append({"name": "radio1", "device": "x", "robots": [1]}), "robot 1 is behind both"),
    (lambda d: d["ports"][0].update(transport="wifi"), "ports[0].transport"),
    (lambda d: d["ports"][0].update(baud=True), "ports[0].baud"),
    (lambda d: d.update(calibration={"5": {}}), "robot 5 is behind no port"),
    (lambda d: d.update(calibration={"1": {"motion_scale": 0}}), "calibration['1'].motion_scale: must be > 0"),
    (lambda d: d.update(calibration={"1": {"range_bias_m": float("nan")}}), "must be a finite number"),
    (lambda d: d.update(calibration={"1": {"scale": 1}}), "unknown field(s) ['scale']"),
    (lambda d: d.update(timing={"heartbeat_period_s": 2.0}), "heartbeat_period_s (2.0) must be below heartbeat_timeout_s"),
    (lambda d: d.update(timing={"heartbeat_timeout_s": 1.0}), "heartbeat_timeout_s (1) must exceed the retry budget plus one retransmission (1.7 s)"),
    (lambda d: d.update(timing={"max_retries": -1}), "timing.max_retries"),
    (lambda d: d.update(timing={"ack_timeout_s": 0.2, "max_retries": 15}), "ack_timeout_s x (max_retries + 1) = 3.2 s is too long"),
    (lambda d: d.update(timing={"robot_timeout_s": 6.0}), "timing.robot_timeout_s: 6 s must stay below the coordinator's step timeout 5 s"),
    (lambda d: d.update(limits={"workspace": [0, 0, -1, 1]}), "x_min < x_max"),
    (lambda d: d.update(limits={"workspace": [0, 0, 1]}), "limits.workspace"),
    (lambda d: d.update(extra=1), "unknown field(s) ['extra']"),
])
def test_bad_configs_are_named(tmp_path, change, message):
    data = _base()
    change(data)
    path = tmp_path / "gw.json"
    path.write_text(json.dumps(data))
    with pytest.raises(SwarmInputError) as info:
        GatewayConfig.load(path)
    assert message in str(info.value) and str(path) in str(info.value)


def test_unreadable_and_invalid_json(tmp_path):
    with pytest.raises(SwarmInputError, match="cannot read the gateway config"):
        GatewayConfig.load(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("{ports: ")
    with pytest.raises(SwarmInputError, match="is not valid JSON"):
        GatewayConfig.load(tmp_path / "bad.json")
    with pytest.raises(SwarmInputError, match="robot 9 is behind no port"):
        GatewayConfig.from_json(_base()).port_of(9)


def test_calibration_undoes_the_robot_deviation():
    c = Calibration(range_bias_m=0.02, bearing_offset_rad=0.1, motion_scale=0.9)
    assert c.corrected_drive(0.09) == pytest.approx(0.1)
    assert c.corrected_range(0.32) == pytest.approx(0.30) and c.corrected_range(0.01) == 0.0
    assert c.corrected_bearing(math.pi - 0.05 + 0.1 - 2 * math.pi) == pytest.approx(math.pi - 0.05)
    assert c.corrected_bearing(-math.pi + 0.05) == pytest.approx(math.pi - 0.05)
    # the deviation the emulator applies and the agent's correction are inverses
    true_r, true_b = np.array([0.3, 0.0, 0.45]), np.array([0.2, math.pi - 0.05, -3.1])
    assert [c.corrected_range(r) for r in c.measured_ranges(true_r)] == pytest.approx(true_r.tolist())
    assert [c.corrected_bearing(b) for b in c.measured_bearings(true_b)] == pytest.approx(true_b.tolist())
    assert c.corrected_drive(c.driven(0.2)) == pytest.approx(0.2)
    ideal = Calibration()
    assert ideal.measured_ranges(true_r) is true_r and ideal.measured_bearings(true_b) is true_b  # bit for bit


def test_workspace_limit_uses_the_predicted_end_position():
    limits = CommandLimits(max_drive_m=1.0, workspace=(0.0, 0.0, 1.0, 1.0))

    def cmd(start):
        return MotionCommand(run="r", step=1, robot=0, config=1, turn_rad=math.pi / 2, drive_m=0.5, start_pose=start)

    assert limits.refusal(cmd((0.5, 0.2, 0.0))) is None  # ends at (0.5, 0.7)
    reason = limits.refusal(cmd((0.5, 0.7, 0.0)))  # would end at (0.5, 1.2)
    assert reason is not None and "outside the workspace" in reason and "(0.500, 1.200)" in reason
    assert limits.refusal(cmd(())) is None  # no estimate: the workspace cannot be checked
    with pytest.raises(SwarmInputError, match="workspace"):
        CommandLimits(workspace=(0, 0, 0, 1))


def test_ant_device_strings_and_missing_openant():
    assert parse_ant_device("ant:17") == (17, 66) and parse_ant_device("ant:17:57") == (17, 57)
    for bad in ("ant:", "ant:0", "usb:1", "ant:1:200", "ant:70000"):
        with pytest.raises(SwarmInputError, match="ANT device"):
            parse_ant_device(bad)
    if importlib.util.find_spec("openant") is None:
        with pytest.raises(SwarmInputError, match=r"pip install -e '\.\[ant\]'"):
            AntLink("ant:17")


def test_retry_budgets_derive_from_one_budget_below_the_coordinators_step_timeout():
    from coordinator.node.zenoh_backend import Timeouts
    from runtime.gateway.config import STEP_TIMEOUT_S, Timing

    assert STEP_TIMEOUT_S == Timeouts().step_s  # the coordinator's default the gateway config is checked against
    t = Timing()
    assert t.retry_budget_s == pytest.approx(t.ack_timeout_s * (t.max_retries + 1)) == pytest.approx(1.6)
    assert t.resend_s > t.retry_budget_s  # the agent re-sends only once the link has given up on its copy
    assert t.answer_timeout_s(motion=False) < STEP_TIMEOUT_S and t.robot_timeout_s < STEP_TIMEOUT_S
    assert t.answer_timeout_s(motion=True) == pytest.approx(t.answer_timeout_s(motion=False) + t.motion_timeout_s)
    # a lost DONE costs one retry interval: the link re-sends every ack_timeout_s, also after ACCEPTED
    assert t.ack_timeout_s < t.heartbeat_timeout_s / 5
