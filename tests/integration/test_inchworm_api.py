"""The Python API (``inchworm``): the study runner and its log, typed options, results, plots and layering."""

from __future__ import annotations

import ast
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure
from scipy import stats

import inchworm
from inchworm.comparison import run_one
from inchworm.noise import scaled
from inchworm.runner import ProcessExecutor, SerialExecutor, StudyLog, run_tasks
from inchworm.stats import clipped_at_zero, mean_ci, paired_p_value
from runtime.errors import SwarmError, SwarmInputError
from runtime.models.config import ModelConfig
from swarm_cli.main import build_parser
from swarm_cli.options import apply_config

REPO = Path(__file__).resolve().parents[2]
SMALL = inchworm.CompareOptions(robots=6, trajectories=3, configs=2, methods=("ref57", "no-anchors", "heuristic-fixed"))


@dataclass(frozen=True)
class Square:
    x: int

    @property
    def key(self) -> str:
        return str(self.x)


def square(task: Square) -> dict:
    return {"x": task.x, "y": task.x**2 + 0.1}


def failing_at(x: int):
    def run(task: Square) -> dict:
        if task.x == x:
            raise RuntimeError(f"square({x}) failed")
        return square(task)
    return run


def without_cpu(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "cpu_s"} for r in rows]


def test_an_interrupted_study_resumes_to_the_same_rows(tmp_path):
    tasks = [Square(x) for x in range(6)]
    with pytest.raises(RuntimeError, match=r"square\(4\)"):
        run_tasks(failing_at(4), tasks, log=StudyLog(tmp_path, "runs", {"n": 6}))
    kept = (tmp_path / "runs.jsonl").read_text().splitlines()
    assert len(kept) == 1 + 4 and json.loads(kept[0]) == {"options": {"n": 6}}
    assert len((tmp_path / "runs.csv").read_text().splitlines()) == 1 + 4  # the CSV follows every finished row
    with open(tmp_path / "runs.jsonl", "a") as f:
        f.write('{"task": "5", "row": {"x": 5, "y"')  # the line being written when the study was killed
    seen: list[int] = []
    rows = run_tasks(lambda t: seen.append(t.x) or square(t), tasks, log=StudyLog(tmp_path, "runs", {"n": 6}, resume=True))
    assert seen == [4, 5]  # only what was missing ran again
    assert rows == [square(t) for t in tasks]


def test_resume_refuses_a_log_of_other_options(tmp_path):
    StudyLog(tmp_path, "runs", {"robots": 6, "seed": 0})
    with pytest.raises(inchworm.OptionError, match=r"^resume: .*runs\.jsonl was made with robots = 6, not 8$") as caught:
        StudyLog(tmp_path, "runs", {"robots": 8, "seed": 0}, resume=True)
    assert caught.value.flag_message().startswith("--resume: ")
    (tmp_path / "other.jsonl").write_text("not a log\n")
    with pytest.raises(SwarmInputError, match="is not a study log"):
        StudyLog(tmp_path, "other", {}, resume=True)


def test_rows_do_not_depend_on_the_workers_or_their_order():
    tasks = SMALL.tasks()
    serial = run_tasks(run_one, tasks, executor=SerialExecutor())
    pooled = run_tasks(run_one, tasks, executor=ProcessExecutor(2))
    assert without_cpu(serial) == without_cpu(pooled)
    assert [(r["trajectory"], r["method"]) for r in pooled] == [(t.t, t.method) for t in tasks]


def test_compare_pairs_the_methods_on_seed_plus_t():
    """Trajectory t is drawn from [seed, t] (keeping the model's bodies apart) and every method runs it with the seed seed + t."""
    from coordinator.simulate import simulate
    from inchworm.seeding import paired_trajectory
    from runtime.models.trajectory import body_spacing

    result = inchworm.compare(SMALL, executor=SerialExecutor())
    row = next(r for r in result.rows if r["trajectory"] == 2 and r["method"] == "ref57")
    traj = paired_trajectory(6, 2, 0, 2, ModelConfig().sensing_range_m, **body_spacing(ModelConfig()))
    assert row["pf"] == simulate(traj, "ref57", ModelConfig(), seed=2).pf()
    doc = result.to_json()
    assert list(doc) == ["methods", "p_values"] and set(doc["p_values"]) == {"no-anchors", "heuristic-fixed"}
    ref = [r["pf"] for r in result.rows if r["method"] == "ref57"]
    assert doc["methods"]["ref57"]["pf_ci97"] == pytest.approx(list(stats.t.interval(0.97, 2, np.mean(ref), stats.sem(ref))), rel=1e-12)
    assert "ref57" in result.report() and json.dumps(doc)


def test_statistics_and_noise_scaling():
    v = np.array([0.01, 0.02, 0.07])
    lo, hi = mean_ci(v)
    assert lo < 0 < v.mean() < hi and clipped_at_zero(lo, hi) == (0.0, hi)
    assert math.isnan(mean_ci(np.array([0.1]))[0])
    assert paired_p_value(v, v + np.array([0.001, 0.002, 0.0])) == pytest.approx(stats.ttest_rel(v, v + [0.001, 0.002, 0.0]).pvalue)
    cfg = scaled(ModelConfig(), motion=2.0, sensing=0.5)
    assert cfg.turn_sigma_rad == 2 * ModelConfig().turn_sigma_rad and cfg.range_sigma_m == 0.5 * ModelConfig().range_sigma_m
    assert cfg.sensing_range_m == ModelConfig().sensing_range_m


def test_bad_options_are_one_error_hierarchy():
    """Options are checked when they are made; the library names the Python parameter, never a flag."""
    with pytest.raises(SwarmError, match=r"^methods must list names among .*; unknown: \['teleport'\]$"):
        inchworm.compare(inchworm.CompareOptions(methods=("teleport",)))
    with pytest.raises(SwarmInputError, match="^localizers must list localizers"):
        inchworm.study_noise(inchworm.NoiseOptions(localizers=("gps",)))
    with pytest.raises(inchworm.OptionError, match="^experiments must be >= 1, got 0$") as caught:
        inchworm.AnchorsOptions(experiments=0)
    assert caught.value.parameter == "experiments" and caught.value.flag_message() == "--experiments must be >= 1, got 0"
    with pytest.raises(inchworm.OptionError, match="^trajectories must be >= 1, got 0$"):
        inchworm.compare(inchworm.CompareOptions(trajectories=0))
    with pytest.raises(inchworm.OptionError, match="^max_motion_scale must be > 1"):
        inchworm.CalibrationOptions(max_motion_scale=1.0)
    with pytest.raises(inchworm.OptionError, match="^localizer must be one of the localizers"):
        inchworm.RunOptions(localizer="gps")


@pytest.mark.parametrize("argv, flag_message", [
    (["study", "noise", "--localizers", "gps"], "--localizers must list localizers among"),
    (["study", "calibration", "--max-motion-scale", "1"], "--max-motion-scale must be > 1, got 1.0"),
    (["study", "anchors", "--experiments", "0"], "--experiments must be >= 1, got 0"),
    (["study", "selection", "--eval-samples", "0"], "--eval-samples must be >= 1, got 0"),
    (["study", "noise", "--robots", "1"], "--robots must be >= 2, got 1"),
])
def test_the_cli_names_the_flag_of_a_bad_option(argv, flag_message, capsys):
    from swarm_cli.main import main

    assert main(argv) == 2
    err = capsys.readouterr().err
    assert flag_message in err and len(err.strip().splitlines()) == 1, err


def test_results_plot_on_the_callers_axes_with_full_titles():
    result = inchworm.compare(SMALL, executor=SerialExecutor())
    fig = Figure(figsize=(4, 3))
    ax = fig.add_subplot()
    assert result.plot(ax) is ax
    assert ax.get_ylim()[0] == 0.0 and all(b >= 0 for b in ax.containers[-1][2][0].get_segments()[0][:, 1])
    text = ax.get_title().replace("\n", " ")
    assert text == "3 trajectories x 2 configurations, n_r = 6"  # wrapped on a narrow figure, never cut
    run = inchworm.simulate(robots=6, configs=2, seed=1)
    axes = Figure().subplots(1, 2)
    inchworm_plots = __import__("inchworm.plots", fromlist=["plot_errors"])
    inchworm_plots.plot_errors({"inchworm": run, "ref57": inchworm.simulate(run.trajectory, method="ref57", seed=1)}, axes)
    assert [t.get_text().split(" (")[0] for t in axes[0].get_legend().get_texts()] == ["inchworm", "ref57"]
    legend = [t.get_text() for t in inchworm_plots.plot_trajectory(run, Figure().add_subplot()).get_legend().get_texts()]
    assert {"earlier configurations (hollow)", "last configuration (filled)", "anchors of a configuration's first step"} <= set(legend)


def test_custom_strategy_and_localizer_plug_in():
    from coordinator.localization.dead_reckoning import dead_reckon
    from coordinator.plan import Plan

    class Halves:
        name = "halves"

        def plan(self, estimate, desired):
            return Plan.equal(np.arange(len(desired)), len(desired) // 2), None

        def restrict(self, keep):
            return self

    class NoObservations:
        name = "dead-reckoning"

        def localize(self, prior, step, obs):
            return dead_reckon(prior, step, ModelConfig())

        def localize_subset(self, prior, step, obs, keep):
            return dead_reckon(prior, step, ModelConfig())

    run = inchworm.simulate(robots=6, configs=2, seed=4, method=Halves())
    assert list(run.anchor_counts()) == [3, 3] and run.method == "halves"
    blind = inchworm.simulate(robots=6, configs=2, seed=4, method=Halves(), localizer=NoObservations())
    assert blind.localization_errors()[-1] > run.localization_errors()[-1]  # localization is worth something


def test_simulate_takes_options_or_the_keywords_that_make_them(tmp_path):
    """``simulate(SimOptions(...))`` is the run its keywords give; the trajectory as the first argument or a file."""
    chosen = inchworm.SimOptions(robots=6, configs=2, method="ref57", seed=5, model=ModelConfig(turn_sigma_rad=math.radians(6)))
    run = inchworm.simulate(chosen)
    same = [inchworm.simulate(robots=6, configs=2, method="ref57", seed=5, model=ModelConfig(turn_sigma_rad=math.radians(6))),
            inchworm.simulate(options=chosen)]
    file = tmp_path / "t.json"
    run.trajectory.save(file)
    same += [inchworm.simulate(run.trajectory, method="ref57", seed=5, model=chosen.model, selection=None),
             inchworm.simulate(inchworm.SimOptions(trajectory=str(file), method="ref57", seed=5, model=chosen.model))]
    for other in same:
        assert np.array_equal(other.estimated_configurations(), run.estimated_configurations()) and other.pf() == run.pf()
    with pytest.raises(TypeError, match="not both"):
        inchworm.simulate(chosen, seed=6)
    with pytest.raises(TypeError, match="trajectory twice"):
        inchworm.simulate(run.trajectory, trajectory=file)


def test_a_study_file_gives_defaults_that_flags_override(tmp_path):
    parser = build_parser(["compare"])
    sub = parser.parse_args(["compare"])._study_parser
    (tmp_path / "s.toml").write_text('robots = 8\nmethods = ["ref57", "no-anchors"]\nturn-sigma-deg = 6.0\n')
    apply_config(sub, tmp_path / "s.toml")
    args = parser.parse_args(["compare", "--robots", "12"])
    assert (args.robots, args.methods, args.turn_sigma_deg) == (12, "ref57,no-anchors", 6.0)
    (tmp_path / "bad.toml").write_text("robots = 8\nrobts = 9\n")
    with pytest.raises(SwarmInputError, match="unknown key 'robts'"):
        apply_config(build_parser(["compare"]).parse_args(["compare"])._study_parser, tmp_path / "bad.toml")


def _imports(package: str) -> set[str]:
    found = set()
    for path in (REPO / package).rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                found.add(node.module.split(".")[0])
            elif isinstance(node, ast.Import):
                found.update(a.name.split(".")[0] for a in node.names)
    return found


def test_layering():
    for package in ("runtime", "coordinator", "robot_agent"):
        assert not _imports(package) & {"inchworm", "swarm_cli"}, package
    assert "swarm_cli" not in _imports("inchworm")
    assert (REPO / "inchworm" / "py.typed").exists()


@pytest.mark.parametrize("study, options, log", [
    ("study_anchors", inchworm.AnchorsOptions(robots=4, experiments=3, samples=2), "experiments"),
    ("study_consistency", inchworm.ConsistencyOptions(localizers=("paper",), methods=("no-anchors", "ref57"), robots=4, configs=2, trajectories=2),
     "runs"),
])
def test_a_study_cut_after_one_row_resumes_to_the_same_result(tmp_path, study, options, log):
    run = getattr(inchworm, study)
    whole = run(options, out=tmp_path / "whole")
    run(options, out=tmp_path / "cut")
    jsonl = tmp_path / "cut" / f"{log}.jsonl"
    jsonl.write_text("".join(jsonl.read_text().splitlines(keepends=True)[:2]))  # the options and one finished row
    resumed = run(options, out=tmp_path / "cut", resume=True)
    assert resumed.to_json() == whole.to_json()
    assert (tmp_path / "cut" / f"{log}.csv").read_text() == (tmp_path / "whole" / f"{log}.csv").read_text()
