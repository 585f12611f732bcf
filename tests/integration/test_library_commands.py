"""The library behind ``swarm replay`` and ``swarm launch`` called directly with typed options."""

from __future__ import annotations

from pathlib import Path

import pytest

import inchworm
from inchworm.launcher import DriverOptions, FaultOptions, OutputOptions, SwarmOptions
from runtime.errors import SwarmInputError

SAMPLE = Path(__file__).resolve().parents[2] / "recordings" / "sample.mcap"


def test_check_recording_reproduces_the_sample_and_refuses_a_contradiction() -> None:
    outcome = inchworm.check_recording(inchworm.CheckOptions(SAMPLE))
    assert outcome.result.passed and outcome.against == []
    assert outcome.to_json()["estimates"] == 16 and outcome.to_json()["plans"] == 9
    with pytest.raises(inchworm.OptionError, match=r"^what_if is not set and localizer joint \(recorded: paper\), seed 3 "
                                                    r"\(recorded: 0\) contradicts .* or set what_if to re-run") as caught:
        inchworm.check_recording(inchworm.CheckOptions(SAMPLE, localizer="joint", seed=3))
    assert "--" not in str(caught.value)  # Python names; the command line's flags:
    assert caught.value.flag_message().startswith("--what-if is not set and --localizer joint (recorded: paper), --seed 3 (recorded: 0)")
    model = inchworm.check_recording(inchworm.CheckOptions(SAMPLE, model_flags={"turn_sigma_deg": 4.0}, what_if=True))
    assert model.against == ["turn_sigma_deg 4.0 (recorded: 3)"] and model.against_flags == ["--turn-sigma-deg 4.0 (recorded: 3)"]
    what_if = inchworm.check_recording(inchworm.CheckOptions(SAMPLE, localizer="joint", what_if=True))
    assert not what_if.result.passed and what_if.against == ["localizer joint (recorded: paper)"]
    assert what_if.against_flags == ["--localizer joint (recorded: paper)"]


def test_check_recording_keeps_a_recorded_model_value_given_in_degrees() -> None:
    outcome = inchworm.check_recording(inchworm.CheckOptions(SAMPLE, model_flags={"turn_sigma_deg": 3.0}))
    assert outcome.result.passed and outcome.model == {}  # 3 deg is the recorded value: the exact recorded radians are used


def test_publish_refuses_a_negative_speed_before_reading_the_file(tmp_path) -> None:
    with pytest.raises(inchworm.OptionError, match="^speed must be >= 0"):
        inchworm.publish(inchworm.PublishOptions(tmp_path / "missing.mcap", speed=-1.0))
    with pytest.raises(inchworm.OptionError, match="^wait must be >= 0") as caught:
        inchworm.PublishOptions(tmp_path / "missing.mcap", wait=-1.0)
    assert caught.value.flag_message() == "--wait must be >= 0, got -1.0"


@pytest.mark.parametrize(("options", "message"), [
    (lambda: inchworm.LaunchOptions(faults=FaultOptions(drop=0.1)),
     "drop is a fault of the emulated robots' radio and links: it needs the gateway driver"),
    (lambda: inchworm.LaunchOptions(swarm=SwarmOptions(robots=3, min_robots=5)), "min_robots must be between 2 and the 3 robots of the run, got 5"),
    (lambda: inchworm.LaunchOptions(swarm=SwarmOptions(robots=3), faults=FaultOptions(kill_robot=(9, 1))),
     "kill_robot 9@1: robot 9 is not one of the run's robots [0, 1, 2]"),
    (lambda: inchworm.LaunchOptions(swarm=SwarmOptions(run_id="bad/id")), "run_id 'bad/id'"),
    (lambda: inchworm.LaunchOptions(swarm=SwarmOptions(robots=1)), "robots must be >= 2, got 1"),
    (lambda: inchworm.LaunchOptions(faults=FaultOptions(stall_coordinator=(0, 3.0))), "stall_coordinator 0:3: the step must be >= 1"),
])
def test_launch_refuses_bad_options_before_starting_anything(monkeypatch, options, message) -> None:
    """Library errors name the Python parameter (the command line names its flag: tests/unit/test_errors.py)."""
    import inchworm.launcher as module

    def refuse(*_a, **_k):
        raise AssertionError("a process or the hub was started before the input was checked")

    monkeypatch.setattr(module.subprocess, "Popen", refuse)
    monkeypatch.setattr(module, "open_loopback_hub", refuse)
    with pytest.raises(SwarmInputError) as caught:
        inchworm.launch(options())
    assert str(caught.value).startswith(message) and "--" not in str(caught.value)


def test_launch_options_are_keyword_only_and_take_str_paths() -> None:
    with pytest.raises(TypeError):
        SwarmOptions("trajectory.json")  # type: ignore[misc]
    options = inchworm.LaunchOptions(swarm=SwarmOptions(trajectory="t.json"), outputs=OutputOptions(out="o", record="r.mcap", result="x.json"),
                                     driver=DriverOptions(name="gateway", gateway_config="g.json", emulator_events="e.jsonl"))
    assert options.swarm.trajectory == Path("t.json") and options.outputs.out == Path("o") and options.outputs.record == Path("r.mcap")
    assert options.outputs.result == Path("x.json") and options.driver.gateway_config == Path("g.json")
    assert options.driver.emulator_events == Path("e.jsonl")
