"""The library behind ``swarm replay`` and ``swarm launch`` called directly with typed options."""

from __future__ import annotations

from pathlib import Path

import pytest

import inchworm
from coordinator.selection.selector import SelectionConfig
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig

SAMPLE = Path(__file__).resolve().parents[2] / "recordings" / "sample.mcap"


def test_check_recording_reproduces_the_sample_and_refuses_a_contradiction() -> None:
    outcome = inchworm.check_recording(inchworm.CheckOptions(SAMPLE))
    assert outcome.result.passed and outcome.against == []
    assert outcome.to_json()["estimates"] == 9 and outcome.to_json()["plans"] == 4
    with pytest.raises(SwarmInputError, match=r"--localizer joint \(recorded: paper\)"):
        inchworm.check_recording(inchworm.CheckOptions(SAMPLE, localizer="joint"))
    what_if = inchworm.check_recording(inchworm.CheckOptions(SAMPLE, localizer="joint", what_if=True))
    assert not what_if.result.passed and what_if.against == ["--localizer joint (recorded: paper)"]


def test_check_recording_keeps_a_recorded_model_value_given_in_degrees() -> None:
    outcome = inchworm.check_recording(inchworm.CheckOptions(SAMPLE, model_flags={"turn_sigma_deg": 3.0}))
    assert outcome.result.passed and outcome.model == {}  # 3 deg is the recorded value: the exact recorded radians are used


def test_publish_refuses_a_negative_speed_before_reading_the_file(tmp_path) -> None:
    with pytest.raises(SwarmInputError, match="--speed must be >= 0"):
        inchworm.publish(inchworm.PublishOptions(tmp_path / "missing.mcap", speed=-1.0))


@pytest.mark.parametrize(("changes", "message"), [
    ({"drop": 0.1}, "need --driver gateway"),
    ({"robots": 3, "min_robots": 5}, "--min-robots 5: must be between 2 and the 3 robots"),
    ({"robots": 3, "kill_robot": (9, 1)}, "--kill-robot 9@1: robot 9 is not one of the run's robots"),
    ({"run_id": "bad/id"}, "--run 'bad/id'"),
])
def test_launch_refuses_bad_options_before_starting_anything(monkeypatch, changes, message) -> None:
    import inchworm.launcher as module

    def refuse(*_a, **_k):
        raise AssertionError("a process or the hub was started before the input was checked")

    monkeypatch.setattr(module.subprocess, "Popen", refuse)
    monkeypatch.setattr(module, "open_session", refuse)
    options = inchworm.LaunchOptions(ModelConfig(), "paper", SelectionConfig(), **changes)
    with pytest.raises(SwarmInputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        inchworm.launch(options)
