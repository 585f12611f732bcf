"""``swarm calibrate`` recovers the noise a launched run was simulated with (agent processes, a real recording)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from inchworm.output import last_json
from runtime.models.model_file import load_model
from runtime.recording.run_log import load_run_log
from runtime.recording.truth_csv import read_truth_csv
from tests.doc_samples import sample, shapes

REPO = Path(__file__).resolve().parents[2]
# unusual noise on every parameter; sensing range smaller than the default 0.5 m
TRUE = {"turn_sigma_deg": 7.0, "drive_sigma_frac": 0.12, "range_sigma_m": 0.03, "bearing_sigma_deg": 5.0, "dropout": 0.2,
        "sensing_range_m": 0.4}
ROBOTS, CONFIGS = 20, 15  # the data volume docs/calibration.md states: 300 motions, ~2000 observations


def swarm(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "swarm_cli.main", *args], cwd=REPO, capture_output=True, text=True, timeout=300)


def test_calibrate_recovers_every_parameter_within_ten_percent(tmp_path):
    rec, truth, model = tmp_path / "run.mcap", tmp_path / "truth.csv", tmp_path / "model.toml"
    # point robots (--robot-radius 0): no-anchors moves every robot once per configuration in one step, the data
    # volume counted below (with bodies a crossing splits the step, docs/bodies.md)
    run = swarm("launch", "-n", str(ROBOTS), "--configs", str(CONFIGS), "--seed", "5", "--method", "no-anchors", "--robot-radius", "0",
                "--agents-per-process", str(ROBOTS), "--turn-sigma-deg", "7", "--drive-sigma-frac", "0.12", "--range-sigma", "0.03",
                "--bearing-sigma-deg", "5", "--dropout", "0.2", "--sensing-range", "0.4", "--record", str(rec),
                "--out", str(tmp_path / "plots"), "--run", f"calib-{tmp_path.name[-12:]}")
    assert run.returncode == 0, run.stderr[-2000:]
    exported = swarm("export", str(rec), "--truth", str(truth), "--json")
    assert exported.returncode == 0, exported.stderr
    # round trip: the CSV holds exactly the recorded true poses, every robot at every step
    log = load_run_log(rec)
    back = read_truth_csv(truth, log.ids)
    assert back.keys() == log.truths.keys() and len(back) == ROBOTS * (CONFIGS + 1)
    assert all(np.array_equal(back[k], log.truths[k]) for k in back)

    fitted = swarm("calibrate", str(rec), "--truth", str(truth), "--out", str(model), "--json")
    assert fitted.returncode == 0, fitted.stderr
    # docs/calibration.md's sample output is what this command prints, line for line (numbers aside; the JSON line added)
    documented, printed = sample("calibration.md", "the run is deterministic for its seed"), fitted.stdout.splitlines()[:-1]
    assert shapes(printed[:-1]) == shapes(documented[:-1]) and len(printed) == len(documented)
    assert documented[-1] == "wrote run.model.toml" and printed[-1] == f"wrote {model}"
    result = last_json(fitted.stdout)
    assert result["samples"]["turns"] == ROBOTS * CONFIGS
    for key, true in TRUE.items():
        assert abs(result[key] / true - 1) < 0.10, (key, result[key], true)
        low, high = result["ci"][key]
        assert low <= true * 1.001 and (high is None or high >= true * 0.999), (key, low, high, true)
    assert not result["systematic"]["drive_scale"]["significant"]
    cfg = load_model(model)
    assert abs(np.degrees(cfg.turn_sigma_rad) / 7.0 - 1) < 0.10 and abs(cfg.dropout_prob / 0.2 - 1) < 0.10


def test_a_launched_run_plans_and_simulates_with_the_model_file_and_records_it(tmp_path):
    model = tmp_path / "lab.toml"
    model.write_text("[model]\nturn_sigma_deg = 6.5\ndropout = 0.1\nsensing_range_m = 0.45\n")
    rec = tmp_path / "run.mcap"
    run = swarm("launch", "-n", "4", "--configs", "2", "--method", "no-anchors", "--model", str(model), "--dropout", "0.05",
                "--mc-start", "estimate", "--mc-emax", "worst", "--record", str(rec), "--out", str(tmp_path / "plots"),
                "--run", f"model-{tmp_path.name[-12:]}")
    assert run.returncode == 0, run.stderr[-2000:]
    from runtime.recording.mcap_log import recording_info

    meta = recording_info(rec)["metadata"]["run"]
    assert meta["model_file"] == model.name  # the file's name: recordings carry no machine paths
    assert meta["model"]["turn_sigma_rad"] == np.radians(6.5) and meta["model"]["sensing_range_m"] == 0.45
    assert meta["model"]["dropout_prob"] == 0.05  # the flag overrides the file
    assert meta["model"]["range_sigma_m"] == 0.01  # not in the file: the default
    assert (meta["selection"]["mc_start"], meta["selection"]["mc_emax"]) == ("estimate", "worst")  # forwarded to the coordinator
