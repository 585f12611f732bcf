"""``inchworm.SimOptions``, the options of one simulated run (``inchworm.simulate``, ``swarm sim``): checked once when
made, each problem naming the field (the command line: its flag); what the flags of ``swarm sim`` make."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from coordinator.localization.registry import localizer_names
from inchworm.sim_options import SimOptions
from runtime.errors import OptionError
from runtime.models.config import ModelConfig
from runtime.world.params import PhysicsParams
from swarm_cli.main import build_parser
from swarm_cli.sim import options


@pytest.mark.parametrize(("given", "message", "flag_message"), [
    ({"robots": 1}, "robots must be >= 2 for a random trajectory, got 1", "--robots must be >= 2 for a random trajectory, got 1"),
    ({"configs": 0}, "configs must be >= 1 for a random trajectory, got 0", "--configs must be >= 1 for a random trajectory, got 0"),
    ({"method": "teleport"}, "method must be one of inchworm, inchworm-equal-speed, heuristic-fixed, ref57, no-anchors, one-at-a-time "
     "(or a Strategy), got 'teleport'", None),
    ({"localizer": "kalman"}, f"localizer must be one of the localizers {', '.join(localizer_names())}, got 'kalman'", None),
    ({"world": "moon"}, "world must be 'model' or 'physics', got 'moon'", None),
    ({"physics": PhysicsParams.for_model(ModelConfig())}, "physics sets the physical world: it needs world physics",
     "--physics-param sets the physical world: it needs --world physics"),
    ({"seed": -1}, "seed must be >= 0, got -1", None),
    ({"initial_delta_m": -0.01}, "initial_delta_m must be >= 0, got -0.01", None),
    ({"initial_heading_sigma_rad": math.nan}, "initial_heading_sigma_rad must be >= 0, got nan", None),
    ({"trajectory": 7}, "trajectory must be a Trajectory or a trajectory JSON file, got int", None),
])
def test_each_bad_option_is_named(given, message, flag_message):
    with pytest.raises(OptionError) as caught:
        SimOptions(**given)
    assert str(caught.value) == message
    if flag_message is not None:
        assert caught.value.flag_message() == flag_message


def test_a_given_trajectory_file_is_a_path_and_the_random_one_is_not_checked():
    chosen = SimOptions(trajectory="runs/t.json", robots=0, configs=0)  # robots and configs are the random trajectory's
    assert chosen.trajectory == Path("runs/t.json")
    with pytest.raises(TypeError):
        SimOptions("runs/t.json")  # keyword-only: a positional value is refused


def test_the_flags_make_the_options():
    pytest.importorskip("pymunk")  # --world physics checks that its extra is installed
    argv = ["sim", "--trajectory", "t.json", "--method", "ref57", "--seed", "3", "--localizer", "joint", "--robot-radius", "0",
            "--samples", "4", "--world", "physics", "--physics-param", "mass_kg=0.05"]
    chosen = options(build_parser(argv).parse_args(argv))
    assert (chosen.trajectory, chosen.method, chosen.seed, chosen.localizer) == (Path("t.json"), "ref57", 3, "joint")
    assert (chosen.model.robot_radius_m, chosen.selection.samples, chosen.world, chosen.physics) == (
        0.0, 4, "physics", PhysicsParams.for_model(chosen.model, mass_kg=0.05))
    assert (chosen.initial_delta_m, chosen.initial_heading_sigma_rad) == (0.01, math.radians(2.0))  # no flags: the defaults
