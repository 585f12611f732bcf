"""``inchworm.new_trajectory`` and ``check_trajectory`` (``swarm trajectory new|check``): the options or their keywords,
the file written and checked, bad options named by their field (the command line: their flag)."""

from __future__ import annotations

import dataclasses

import pytest

import inchworm
from runtime.errors import OptionError, SwarmInputError


def test_a_written_trajectory_checks_and_options_equal_keywords(tmp_path):
    options = inchworm.NewTrajectoryOptions(file=str(tmp_path / "sub" / "t.json"), robots=5, configs=2, seed=3, step=0.2)
    written = inchworm.new_trajectory(options)
    assert written.file == tmp_path / "sub" / "t.json" and written.summary["robots"] == 5 and written.summary["configs"] == 2
    again = inchworm.new_trajectory(**{**vars(options), "file": tmp_path / "u.json"})
    assert again.trajectory.to_json() == written.trajectory.to_json()
    checked = inchworm.check_trajectory(str(written.file), sensing_range=0.5)
    assert checked.to_json() == written.to_json()
    assert inchworm.check_trajectory(inchworm.CheckTrajectoryOptions(file=written.file)).to_json() == checked.to_json()
    with pytest.raises(SwarmInputError, match=r"^trajectory .*t\.json: the initial configuration is not connected"):
        inchworm.check_trajectory(written.file, sensing_range=0.01)
    with pytest.raises(TypeError, match="not both"):
        inchworm.new_trajectory(options, robots=4)


@pytest.mark.parametrize(("field", "value", "flag", "problem"), [
    ("robots", 20_000, "--robots", " 20000: at most 10000 (simulated robots)"),
    ("seed", -1, "--seed", " -1: must be between 0 and 2^63 - 1 (numpy seeds are >= 0 and int64)"),
    ("configs", 2.5, "--configs", " must be an integer, got 2.5"),
    ("step", float("nan"), "--step", " must be a finite number > 0, got nan"),
    ("sensing_range", 0, "--sensing-range", " must be a finite number > 0, got 0"),
])
def test_bad_options_name_their_field_and_flag(field, value, flag, problem):
    with pytest.raises(OptionError) as caught:
        inchworm.NewTrajectoryOptions(file="t.json", **{field: value})
    assert str(caught.value) == field + problem and caught.value.flag_message() == flag + problem
    with pytest.raises(OptionError, match="^sensing_range must be"):
        dataclasses.replace(inchworm.CheckTrajectoryOptions(file="t.json"), sensing_range=-1.0)
