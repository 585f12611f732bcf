"""Every path parameter of the public library (``inchworm``'s names) takes a plain ``str`` as well as a ``Path``."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

import inchworm
from runtime.recording.truth_csv import export_truth

REPO = Path(__file__).resolve().parents[1]
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


def test_trajectories_and_runs_take_str_paths(tmp_path):
    run = inchworm.simulate(robots=4, configs=1, method="no-anchors", seed=3)
    file = str(tmp_path / "trajectory.json")
    run.trajectory.save(file)
    assert inchworm.Trajectory.load(file).to_json() == run.trajectory.to_json()
    again = inchworm.simulate(file, method="no-anchors", seed=3)
    assert again.pf() == run.pf()


def test_localize_takes_a_str_path(tmp_path):
    document = {"robots": [11, 12, 13], "observations": [[11, 12, 0.304, 1.021], [12, 11, 0.301, -2.650], [11, 13, 0.3, 0.5],
                                                          [13, 11, 0.31, -2.6], [12, 13, 0.28, 2.1]]}
    file = tmp_path / "data.json"
    file.write_text(json.dumps(document), encoding="utf-8")
    assert inchworm.localize(str(file)).to_json() == inchworm.localize(document).to_json()


def test_recording_options_take_str_paths():
    check = inchworm.CheckOptions(SAMPLE, trajectory="t.json", model_file="m.toml")
    assert (check.file, check.trajectory, check.model_file) == (Path(SAMPLE), Path("t.json"), Path("m.toml"))
    assert inchworm.PublishOptions(SAMPLE).file == Path(SAMPLE)


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
