"""The limits of sizes and seeds (``inchworm.limits``) hold for the library's options too, not only for the command line:
each options class refuses an absurd size or a seed numpy cannot take when it is made, naming the field (the command
line: its flag), with the same words as ``swarm``'s own check."""

from __future__ import annotations

import pytest

import inchworm
from inchworm.limits import MAX_CONFIGS, MAX_LAUNCHED_ROBOTS, MAX_ROBOTS, MAX_SEED, MAX_TRAJECTORIES, check_limits
from runtime.errors import OptionError, SwarmInputError

CASES = [  # options class, field, value beyond its limit, the problem
    ("SimOptions", "robots", MAX_ROBOTS + 1, f"{MAX_ROBOTS + 1}: at most {MAX_ROBOTS} (simulated robots)"),
    ("SimOptions", "seed", MAX_SEED + 1, f"{MAX_SEED + 1}: must be between 0 and 2^63 - 1 (numpy seeds are >= 0 and int64)"),
    ("CompareOptions", "trajectories", MAX_TRAJECTORIES + 1,
     f"{MAX_TRAJECTORIES + 1}: must be between 1 and {MAX_TRAJECTORIES} (random trajectories)"),
    ("CompareOptions", "configs", MAX_CONFIGS + 1, f"{MAX_CONFIGS + 1}: at most {MAX_CONFIGS} (configurations of a random trajectory)"),
    ("AnchorsOptions", "seed", -3, "-3: must be between 0 and 2^63 - 1 (numpy seeds are >= 0 and int64)"),
    ("NoiseOptions", "trajectories", MAX_TRAJECTORIES + 1, f"{MAX_TRAJECTORIES + 1}: must be between 1 and {MAX_TRAJECTORIES} (random trajectories)"),
    ("ConsistencyOptions", "robots", MAX_ROBOTS + 1, f"{MAX_ROBOTS + 1}: at most {MAX_ROBOTS} (simulated robots)"),
    ("SelectionStudyOptions", "seed", -1, "-1: must be between 0 and 2^63 - 1 (numpy seeds are >= 0 and int64)"),
    ("CalibrationOptions", "configs", MAX_CONFIGS + 1, f"{MAX_CONFIGS + 1}: at most {MAX_CONFIGS} (configurations of a random trajectory)"),
    ("SwarmOptions", "robots", MAX_LAUNCHED_ROBOTS + 1,
     f"{MAX_LAUNCHED_ROBOTS + 1}: at most {MAX_LAUNCHED_ROBOTS} (robots launched as agent processes on one host)"),
    ("SwarmOptions", "trajectory_seed", -1, "-1: must be between 0 and 2^63 - 1 (numpy seeds are >= 0 and int64)"),
]


@pytest.mark.parametrize(("cls", "name", "value", "problem"), CASES)
def test_options_refuse_a_size_or_seed_beyond_the_limits_naming_the_field(cls, name, value, problem):
    with pytest.raises(OptionError) as caught:
        getattr(inchworm, cls)(**{name: value})
    assert caught.value.parameter == name and str(caught.value) == f"{name} {problem}"
    assert caught.value.flag_message().endswith(f" {problem}") and "--" not in str(caught.value)


def test_the_command_lines_check_says_the_same_with_the_flag():
    with pytest.raises(SwarmInputError, match=rf"^--trajectories {MAX_TRAJECTORIES + 1}: must be between 1 and {MAX_TRAJECTORIES} "):
        check_limits({"trajectories": MAX_TRAJECTORIES + 1})
    with pytest.raises(SwarmInputError, match=rf"^-n/--robots {MAX_LAUNCHED_ROBOTS + 1}: at most {MAX_LAUNCHED_ROBOTS} "):
        check_limits({"robots": MAX_LAUNCHED_ROBOTS + 1}, launched=True)


def test_values_within_the_limits_are_kept():
    assert inchworm.CompareOptions(trajectories=MAX_TRAJECTORIES, seed=MAX_SEED).trajectories == MAX_TRAJECTORIES
    assert inchworm.SwarmOptions(robots=MAX_LAUNCHED_ROBOTS).robots == MAX_LAUNCHED_ROBOTS
