"""``swarm bench envelope``: its rows, its contract and its input checks (the distributed part runs in CI as
the benchmark; its replay and takeover paths are tested in test_replay.py and test_one_master.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from inchworm.bench.envelope import EnvelopeBenchOptions, Point, bench_envelope, in_process_figures
from runtime.errors import SwarmInputError
from swarm_cli.main import main

KEYS = {"noise_scale", "robots", "localizer", "sensing_range_m", "replay_identical", "takeover_identical", "nees_median",
        "nees_p95", "contacts_per_100", "pf_mean", "s_per_config", "steps_per_config"}


def test_a_row_per_point_with_the_contract_keys_and_scaled_noise():
    o = EnvelopeBenchOptions(noise_scales=(1.0, 3.0), robots=(5,), localizers=("joint",), sensing_ranges_m=(0.5,),
                             trajectories=1, configs=2, distributed=False)
    result = bench_envelope(o)
    rows = result.to_json()["rows"]
    assert [(r["noise_scale"], r["robots"], r["localizer"], r["sensing_range_m"]) for r in rows] == [(1.0, 5, "joint", 0.5),
                                                                                                    (3.0, 5, "joint", 0.5)]
    for row in rows:
        assert set(row) == KEYS
        assert row["replay_identical"] is None and row["takeover_identical"] is None  # not measured in process
        assert 0 < row["nees_median"] <= row["nees_p95"] and row["steps_per_config"] >= 1 and row["s_per_config"] > 0
    json.dumps(result.to_json())
    x3 = Point(3.0, 5, "joint", 0.5).model()
    assert x3.turn_sigma_rad == pytest.approx(np.radians(9.0)) and x3.drive_sigma_frac == pytest.approx(0.15)


def test_figures_pool_the_runs_of_a_row():
    runs = [{"nees": [1.0, 3.0], "contacts": 1, "configs": 2, "steps": 3, "pf": 0.1, "cpu_s": 0.2},
            {"nees": [2.0, 4.0], "contacts": 0, "configs": 2, "steps": 2, "pf": 0.3, "cpu_s": 0.6}]
    f = in_process_figures(runs)
    assert f["nees_median"] == 2.5 and f["contacts_per_100"] == 25.0 and f["steps_per_config"] == 1.25
    assert f["pf_mean"] == pytest.approx(0.2) and f["s_per_config"] == pytest.approx(0.2)


@pytest.mark.parametrize(("argv", "named"), [
    (["--noise-scales", "0,1"], "--noise-scales"), (["--robots", "1"], "--robots"), (["--localizers", "nope"], "nope"),
    (["--sensing-ranges", "-1"], "--sensing-ranges"), (["--trajectories", "0"], "--trajectories"),
    (["--distributed-configs", "0"], "--distributed-configs"),
])
def test_bad_options_are_one_line_naming_them(argv, named, capsys):
    assert main(["bench", "envelope", "--no-distributed", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and named in err[0]


def test_validation_names_the_parameter():
    with pytest.raises(SwarmInputError, match="distributed_configs"):
        EnvelopeBenchOptions(distributed_configs=0)
