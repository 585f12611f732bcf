"""Model files, the tracker CSV and the noise fit (quick: one process, the sample recording)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import pytest

from inchworm.output import last_json
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.geometry import wrap_angle
from runtime.models.model_file import load_model, model_toml
from runtime.models.motion import apply_motion
from runtime.models.noise_fit import fit_gauss, fit_noise, fit_range
from runtime.recording.run_log import load_run_log
from runtime.recording.truth_csv import read_truth_csv, write_truth_csv
from swarm_cli.main import main
from swarm_cli.options import add_model_options, model_config

SAMPLE = Path(__file__).resolve().parents[2] / "recordings" / "sample.mcap"


# -- model files -------------------------------------------------------------------------------


def test_model_file_round_trips_and_flags_override_it(tmp_path):
    cfg = ModelConfig(turn_sigma_rad=math.radians(7.0), drive_sigma_frac=0.12, range_sigma_m=0.03,
                      bearing_sigma_rad=math.radians(5.0), sensing_range_m=0.35, dropout_prob=0.2)
    path = tmp_path / "lab.toml"
    path.write_text(model_toml(cfg, {"ci": {"turn_sigma_deg": [6.5, math.inf]}}, "fitted by a test"))
    back = load_model(path)
    for field in cfg.to_dict():
        assert getattr(back, field) == pytest.approx(getattr(cfg, field), rel=1e-12)
    parser = argparse.ArgumentParser()
    add_model_options(parser)
    given = model_config(parser.parse_args(["--model", str(path), "--drive-sigma-frac", "0.3"]))
    assert given.drive_sigma_frac == 0.3  # the flag wins
    assert given.turn_sigma_rad == pytest.approx(math.radians(7.0))  # the file's value
    assert model_config(parser.parse_args([])) == ModelConfig()  # no file: the documented defaults
    partial = tmp_path / "partial.toml"
    partial.write_text("[model]\nrange_sigma_m = 0.02\n")
    assert load_model(partial) == ModelConfig(range_sigma_m=0.02)  # missing keys keep the defaults


@pytest.mark.parametrize("text, named", [
    ("[model]\nturn_sigma = 3.0\n", "model.turn_sigma"),
    ("[model]\ndropout = 1.0\n", "model.dropout"),
    ("[model]\nsensing_range_m = 0\n", "model.sensing_range_m"),
    ("[model]\nrange_sigma_m = -0.01\n", "model.range_sigma_m"),
    ("[model]\nbearing_sigma_deg = \"2\"\n", "model.bearing_sigma_deg"),
    ("[model]\nturn_sigma_deg = nan\n", "model.turn_sigma_deg"),
    ("[model]\ndrive_sigma_frac = true\n", "model.drive_sigma_frac"),
    ("[noise]\nturn_sigma_deg = 3.0\n", "'noise'"),
    ("turn_sigma_deg = 3.0\n", "'turn_sigma_deg'"),
    ("[fit]\n", "no [model] table"),
    ("[model\n", "not TOML"),
])
def test_bad_model_files_name_the_key(tmp_path, capsys, text, named):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SwarmInputError) as raised:
        load_model(path)
    assert str(raised.value).startswith(f"model {path}: ") and named in str(raised.value)  # the CLI: --model (below)
    assert main(["sim", "--robots", "3", "--configs", "1", "--model", str(path), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("swarm sim: error: --model") and named in err[-1]


# -- tracker CSV ---------------------------------------------------------------------------------


def test_truth_csv_round_trips_exactly(tmp_path):
    rows = [(1, 0, 0.1, -0.2, 3.0), (0, 0, 1 / 3, 2 / 7, -math.pi), (0, 1, 1e-17, 5.0, 0.5)]
    write_truth_csv(tmp_path / "t.csv", rows)
    back = read_truth_csv(tmp_path / "t.csv", [0, 1])
    assert {k: v.tolist() for k, v in back.items()} == {(r, s): [x, y, h] for r, s, x, y, h in rows}


@pytest.mark.parametrize("text, message", [
    ("robot,step,x,y\n0,0,1,2\n", "line 1: missing column heading"),
    ("robot,x,y\n0,1,2\n", "line 1: missing columns step, heading"),
    ("robot,step,x,y,heading\n0,0,1,2,0\n70,0,1,2,0\n", "line 3: robot 70 is not a robot of the recording"),
    ("robot,step,x,y,heading\n0,0,1,2,0\n1,0,nan,2,0\n", "line 3: x must be finite"),
    ("robot,step,x,y,heading\n0,0,1,inf,0\n", "line 2: y must be finite"),
    ("robot,step,x,y,heading\n0,0,1,2,north\n", "line 2: heading must be a number"),
    ("robot,step,x,y,heading\n0,-1,1,2,0\n", "line 2: step must be an integer >= 0"),
    ("robot,step,x,y,heading\n0,0,1,2,0\n0,0,1,2,0\n", "line 3: robot 0 step 0 given twice"),
    ("robot,step,x,y,heading\n", "no rows after the header"),
])
def test_bad_truth_csv_names_the_row(tmp_path, capsys, text, message):
    path = tmp_path / "truth.csv"
    path.write_text(text)
    with pytest.raises(SwarmInputError, match=message):
        read_truth_csv(path, range(10))
    if "robot 70" in message:  # through the command: exit 2, one line, nothing written
        assert main(["calibrate", str(SAMPLE), "--truth", str(path), "--out", str(tmp_path / "m.toml")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "line 3: robot 70 is not a robot of the recording" in err[0]
        assert not (tmp_path / "m.toml").exists()


# -- the fit -------------------------------------------------------------------------------------


def _synthetic(rng, n_robots=12, steps=30, turn_bias=0.0, drive_scale=1.0, cfg=ModelConfig()):
    """Commands, observations and truths of robots moving with ``cfg``'s noise plus a systematic error."""
    poses = np.column_stack([rng.uniform(0, 0.6, n_robots), rng.uniform(0, 0.6, n_robots), rng.uniform(-np.pi, np.pi, n_robots)])
    truths = {(r, 0): poses[r].copy() for r in range(n_robots)}
    commands, observations = {}, {}
    for s in range(1, steps + 1):
        cmd = np.column_stack([rng.uniform(-1, 1, n_robots), rng.uniform(0.05, 0.2, n_robots)])
        turn = turn_bias + rng.normal(0, cfg.turn_sigma_rad, n_robots)
        drive = drive_scale * (1 + rng.normal(0, cfg.drive_sigma_frac, n_robots)) - 1
        poses = apply_motion(poses, cmd, turn, drive)
        for r in range(n_robots):
            commands[(r, s)] = tuple(cmd[r])
            truths[(r, s)] = poses[r].copy()
        for i in range(n_robots):
            d = poses[:, :2] - poses[i, :2]
            dist = np.hypot(d[:, 0], d[:, 1])
            seen = np.flatnonzero((dist <= cfg.sensing_range_m) & (np.arange(n_robots) != i))
            seen = seen[rng.random(len(seen)) >= cfg.dropout_prob]
            brg = wrap_angle(np.arctan2(d[seen, 1], d[seen, 0]) - poses[i, 2] + rng.normal(0, cfg.bearing_sigma_rad, len(seen)))
            observations[(i, s)] = (seen, dist[seen] + rng.normal(0, cfg.range_sigma_m, len(seen)), brg)
    return commands, observations, truths


def test_a_systematic_turn_bias_and_drive_scale_are_found_and_significant():
    commands, observations, truths = _synthetic(np.random.default_rng(3), turn_bias=math.radians(2.0), drive_scale=1.1)
    fit = fit_noise(commands, {}, truths).to_json()
    turn, drive = fit["systematic"]["turn_bias_deg"], fit["systematic"]["drive_scale"]
    assert turn["significant"] and turn["ci"][0] < 2.0 < turn["ci"][1]
    assert drive["significant"] and drive["ci"][0] < 1.1 < drive["ci"][1]
    assert fit["turn_sigma_deg"] == pytest.approx(3.0, rel=0.15)  # about the bias, not inflated by it
    # a straight (unbiased) fleet: the same tests do not fire
    commands, observations, truths = _synthetic(np.random.default_rng(4))
    clean = fit_noise(commands, observations, truths).to_json()
    assert not clean["systematic"]["drive_scale"]["significant"]
    assert clean["unidentified"] == []


def test_gauss_fit_intervals_cover_the_truth_at_their_level():
    rng = np.random.default_rng(0)
    fits = [fit_gauss(rng.normal(0.0, 2.0, 50), 0.0) for _ in range(400)]
    coverage = np.mean([f.sigma_null_ci[0] <= 2.0 <= f.sigma_null_ci[1] for f in fits])
    assert 0.92 <= coverage <= 0.98
    false_alarms = np.mean([f.significant for f in fits])
    assert false_alarms < 0.09  # the likelihood-ratio test at 5 %
    assert fit_gauss(np.ones(2), 0.0) is None


def test_sensing_range_is_bounded_only_where_the_data_reach():
    near = np.append(np.linspace(0.01, 0.29, 200), 0.3)  # 201 pairs, every one observed: the dropout is below 2 %
    distances = np.concatenate([near, [0.31, 0.45, 0.5, 0.6]])
    seen = distances <= 0.3
    fit = fit_range(distances, seen)
    assert fit.sensing_range_m == 0.3 and fit.dropout == 0.0 and fit.dropout_ci[1] < 0.02
    assert fit.sensing_range_ci == (0.3, 0.31)  # the first unobserved pair beyond bounds it
    few = fit_range(np.array([0.1, 0.2, 0.3, 0.31]), np.array([True, True, True, False]))
    assert few.sensing_range_ci == (0.3, None)  # 3 pairs cannot exclude a dropout of 70 %: 0.31 may have been dropped
    never_far = fit_range(near, np.ones(len(near), bool))
    assert never_far.sensing_range_ci == (0.3, None)  # censored: nothing says how far the sensor would reach
    assert fit_range(distances, np.zeros(len(distances), bool)) is None


# -- the command on the sample recording ---------------------------------------------------------


def test_calibrate_and_export_truth_on_the_sample(tmp_path, capsys):
    truth = tmp_path / "truth.csv"
    assert main(["export", str(SAMPLE), "--truth", str(truth)]) == 0
    log = load_run_log(SAMPLE)
    back = read_truth_csv(truth, log.ids)
    assert back.keys() == log.truths.keys() and all(np.array_equal(back[k], log.truths[k]) for k in back)
    out = tmp_path / "sample.toml"
    assert main(["calibrate", str(SAMPLE), "--truth", str(truth), "--out", str(out), "--json"]) == 0
    result = last_json(capsys.readouterr().out)
    for key in ("turn_sigma_deg", "drive_sigma_frac", "range_sigma_m", "bearing_sigma_deg", "dropout", "sensing_range_m"):
        assert key in result and key in result["ci"]
    assert result["model_file"] == str(out)
    cfg = load_model(out)  # the file it wrote is a model file every command reads
    assert cfg.range_sigma_m == pytest.approx(result["range_sigma_m"])
    assert main(["sim", "--robots", "4", "--configs", "1", "--model", str(out), "--out", str(tmp_path)]) == 0


def test_a_tracker_on_its_own_clock_gives_the_same_fit(tmp_path, capsys):
    """Rows with ``time`` instead of ``step`` are interpolated at the step ends: a tracker sampling at the step
    ends and halfway between them gives the fit of the per-step truth."""
    log = load_run_log(SAMPLE)
    ends = log.step_end_times()
    timed = tmp_path / "timed.csv"
    lines = ["time,robot,x,y,heading"]
    for (robot, step), pose in sorted(log.truths.items()):
        pose, t = pose.tolist(), ends[(robot, step)]
        lines.append(f"{t!r},{robot},{pose[0]!r},{pose[1]!r},{pose[2] + 2 * np.pi!r}")  # headings need not be wrapped
        if (robot, step + 1) in log.truths:  # halfway to the next step end: not a step end, never used as one
            nxt = log.truths[(robot, step + 1)].tolist()
            mid = (t + ends[(robot, step + 1)]) / 2
            lines.append(f"{mid!r},{robot},{(pose[0] + nxt[0]) / 2!r},{(pose[1] + nxt[1]) / 2!r},{pose[2]!r}")
    timed.write_text("\n".join(lines) + "\n")
    stepped = tmp_path / "stepped.csv"
    assert main(["export", str(SAMPLE), "--truth", str(stepped)]) == 0
    results = []
    for csv_path in (stepped, timed):
        assert main(["calibrate", str(SAMPLE), "--truth", str(csv_path), "--out", str(tmp_path / "m.toml"), "--json"]) == 0
        results.append(last_json(capsys.readouterr().out))
    for key in ("turn_sigma_deg", "drive_sigma_frac", "range_sigma_m", "bearing_sigma_deg", "dropout", "sensing_range_m"):
        assert results[1][key] == pytest.approx(results[0][key], rel=1e-9, abs=1e-12)
    assert results[1]["samples"] == results[0]["samples"]
