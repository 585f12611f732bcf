"""Every path parameter of the public library takes a plain ``str``: those of runs, the noise calibration and the
studies, which read and write recordings and folders (the others: tests/unit/test_str_paths.py)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

import inchworm
from runtime.recording.truth_csv import export_truth

REPO = Path(__file__).resolve().parents[2]
SAMPLE = str(REPO / "recordings" / "sample.mcap")


def test_calibrate_noise_takes_str_paths(tmp_path):
    recording, truth, model = str(tmp_path / "run.mcap"), str(tmp_path / "truth.csv"), str(tmp_path / "model.toml")
    shutil.copyfile(SAMPLE, recording)
    export_truth(recording, truth)
    fit = inchworm.calibrate_noise(recording, truth, model)
    assert fit.model_file == Path(model) and Path(model).read_text(encoding="utf-8").strip()
    assert fit.to_json()["recording"] == recording and fit.to_json()["truth"] == truth
    default = inchworm.calibrate_noise(recording, truth)  # no out: beside the recording
    assert default.model_file == tmp_path / "run.model.toml" and default.model_file.exists()
    options = inchworm.CalibrateOptions(recording=recording, truth=truth, out=model, confidence=0.9)
    assert inchworm.calibrate_noise(options).fit == inchworm.calibrate_noise(recording, truth, out=model, confidence=0.9).fit
    with pytest.raises(TypeError, match="not both"):
        inchworm.calibrate_noise(options, confidence=0.8)


def test_trajectories_and_runs_take_str_paths(tmp_path):
    run = inchworm.simulate(robots=4, configs=1, method="no-anchors", seed=3)
    file = str(tmp_path / "trajectory.json")
    run.trajectory.save(file)
    assert inchworm.Trajectory.load(file).to_json() == run.trajectory.to_json()
    again = inchworm.simulate(file, method="no-anchors", seed=3)
    assert again.pf() == run.pf()


@pytest.mark.parametrize("study, options", [
    ("compare", inchworm.CompareOptions(robots=4, trajectories=1, configs=1, methods=("no-anchors", "ref57"))),
    ("study_anchors", inchworm.AnchorsOptions(robots=4, experiments=1, samples=2)),
    ("study_noise", inchworm.NoiseOptions(motion_scales=(1.0,), sensing_scales=(1.0,), localizers=("paper",), robots=4, trajectories=1,
                                          configs=1)),
    ("study_consistency", inchworm.ConsistencyOptions(localizers=("paper",), methods=("no-anchors", "ref57"), robots=4, configs=1,
                                                      trajectories=1)),
])
def test_studies_take_a_str_out_folder(tmp_path, study, options):
    out = str(tmp_path / "study")
    result = getattr(inchworm, study)(options, out=out)
    assert any(Path(out).glob("*.jsonl"))
    assert all(Path(p).parent == Path(out) for p in result.save(out))
