"""``swarm sim --json`` prints the library's ``SimResult.to_json()`` of the same run, key for key and byte for byte."""

from __future__ import annotations

import json

import pytest

import inchworm
from coordinator.selection.selector import SelectionConfig
from inchworm.output import print_json
from runtime.models.config import ModelConfig
from swarm_cli.main import main


@pytest.mark.parametrize(("flags", "options"), [
    ((), inchworm.SimOptions(robots=6, configs=2)),
    (("--localizer", "joint", "--mc-start", "estimate", "--mc-emax", "worst", "--samples", "4", "--robot-radius", "0.08", "--seed", "1"),
     inchworm.SimOptions(robots=6, configs=2, localizer="joint", seed=1, model=ModelConfig(robot_radius_m=0.08),
                         selection=SelectionConfig(mc_start="estimate", mc_emax="worst", samples=4))),
])
def test_the_command_prints_the_library_object(flags, options, tmp_path, capsys):
    assert main(["sim", "--robots", "6", "--configs", "2", "--baseline", "none", "--out", str(tmp_path), "--json", *flags]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    printed = json.loads(line)
    result = inchworm.simulate(options)
    assert isinstance(result, inchworm.RunResult) and result.options is not None and result.options.trajectory is not None
    assert result.to_json(printed["plots"]) == printed
    print_json(result.to_json(printed["plots"]))
    assert capsys.readouterr().out.strip() == line
    assert printed["plots"] and result.to_json()["plots"] == []


def test_a_result_without_options_says_so():
    run = inchworm.simulate(robots=4, configs=1)
    with pytest.raises(ValueError, match="options"):
        inchworm.SimResult(**{**vars(run), "options": None}).to_json()
