"""Every script of examples/ runs as a user runs it (subprocesses, small sizes) and does what it says."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def example(name: str, *args: str) -> str:
    out = subprocess.run([sys.executable, str(ROOT / "examples" / name), *args], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_one_run(tmp_path):
    text = example("one_run.py", "--robots", "6", "--configs", "2", "--out", str(tmp_path))
    assert "P_f: inchworm" in text
    assert (tmp_path / "trajectory.png").stat().st_size > 0 and (tmp_path / "errors.png").stat().st_size > 0


def test_table1_small_and_its_resume(tmp_path):
    args = ("--robots", "6", "--trajectories", "2", "--configs", "2", "--out", str(tmp_path))
    text = example("table1_small.py", *args)
    assert "ref57: P_f / ref57 = 1.000" in text and (tmp_path / "pf.png").exists()
    assert example("table1_small.py", *args, "--resume").splitlines()[:-1] == text.splitlines()[:-1]


def test_localize_own_data(tmp_path):
    text = example("localize_own_data.py")
    x1 = float(text.splitlines()[2].split("x ")[1].split(" m")[0])
    assert abs(x1 - 0.4) < 0.01  # robot 1 is 0.4 m ahead of robot 0
    assert "left out robot 17: unobserved" in example("localize_own_data.py", str(ROOT / "docs" / "examples" / "localize-prior.json"))
    model = tmp_path / "model.toml"
    model.write_text("[model]\nrange_sigma_m = 0.05\nsensing_range_m = 0.2\n")
    sightings = tmp_path / "one-way.json"  # robot 3 sees 1 and 2 at 0.4 m, nobody sees 3
    sightings.write_text('{"robots": [1, 2, 3], "observations": [[3, 1, 0.4, 0.5], [3, 2, 0.4, -0.7]]}')
    lines = example("localize_own_data.py", str(sightings), "--model", str(model), "--bearing-sigma-deg", "5").splitlines()
    assert lines[0] == "noise model: range 0.05 m, bearing 5 deg, sensing range 0.2 m"
    assert lines[1].startswith("robot 1: x ") and lines[1].endswith("heading unknown (it observed nobody)")
    assert lines[4].startswith("warning: observation rows 0, 1 have ranges beyond the sensing range 0.2 m")


@pytest.mark.parametrize(
    "content,args,message",
    [
        ("{not json", (), "is not valid JSON"),
        ('{"robots": [1, 2], "observations": [[1, 2, 0.3, 0.1]]}', ("--model", "MODEL"), "unknown key model.range_sigma"),
        ('{"robots": [1, 2], "observations": [[1, 2, 0.3, 0.1]]}', ("--range-sigma", "-0.1"), "argument --range-sigma: must be >= 0"),
        ('{"robots": [1, 2], "observations": []}', (), "fewer than two robots can be localized"),
    ],
)
def test_localize_own_data_on_bad_input(tmp_path, content, args, message):
    """Bad data, a bad model file or option: one line on stderr, exit code 2, no traceback."""
    (tmp_path / "in.json").write_text(content)
    (tmp_path / "model.toml").write_text("[model]\nrange_sigma = 0.1\n")
    args = tuple(str(tmp_path / "model.toml") if a == "MODEL" else a for a in args)
    out = subprocess.run([sys.executable, str(ROOT / "examples" / "localize_own_data.py"), str(tmp_path / "in.json"), *args],
                         capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr.startswith("localize_own_data.py: error: ") and message in out.stderr
    assert len(out.stderr.splitlines()) == 1


def test_custom_strategy():
    lines = example("custom_strategy.py", "--robots", "6", "--configs", "2").splitlines()
    assert [line.split(" P_f")[0].strip() for line in lines] == [
        "leaders-first, paper localizer", "ref57, paper localizer", "leaders-first, dead reckoning"]


def test_launched_run(tmp_path):
    """inchworm.Swarm: the live state names every agent, the result is the launch --json object, nothing is left running."""
    text = example("launched_run.py", "--robots", "4", "--configs", "2", "--out", str(tmp_path))
    lines = text.splitlines()
    assert any(line.startswith("run swarm-") and "agents [0, 1, 2, 3] alive" in line for line in lines), text
    status = next(line for line in lines if line.startswith("status "))
    assert status.startswith("status 0, P_f 0.") and "lost robots []" in status
    summary = json.loads(lines[-1])
    assert {"method", "pf", "configs", "lost", "finished_robots", "recording", "ended_early"} <= set(summary)
    assert summary["finished_robots"] == 4 and summary["ended_early"] is None
    assert (tmp_path / "run.mcap").stat().st_size > 0 and (tmp_path / "trajectory.png").exists()


def test_paper_experiment_in_the_physical_world(tmp_path):
    """Sec. 6.2 cheaply: one configuration in this process (``--through ros2`` is the launch tests/system/test_ros2.py runs)."""
    pytest.importorskip("pymunk")
    lines = example("paper_experiment.py", "--through", "in-process", "--configs", "1", "--out", str(tmp_path)).splitlines()
    assert lines[0].startswith("Sec. 6.2: 6 robots, 1 configurations") and "n_a = 3 throughout" in lines[1]
    fixed = lines.index(next(line for line in lines if line.startswith("inchworm-equal-speed: P_f")))
    assert lines[fixed + 2].split()[:3] == ["1", "3", "3"]  # n_a = n_r / 2, the paper's 3
    assert (tmp_path / "trajectory.json").exists() and lines[2].startswith("inchworm: P_f ")
