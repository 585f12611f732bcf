"""``swarm localize`` and ``swarm bench localize`` as a user runs them (real subprocesses)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from coordinator.localization.registry import BUILTIN_LOCALIZERS

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "docs" / "examples"


def swarm(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "swarm_cli.main", *args], capture_output=True, text=True, timeout=300, cwd=ROOT)


@pytest.mark.parametrize("localizer", BUILTIN_LOCALIZERS)
def test_topology_without_prior(localizer):
    out = swarm("localize", str(EXAMPLES / "localize-topology.json"), "--localizer", localizer)
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    assert doc["frame"] == "local" and doc["reference"] == 11
    assert doc["excluded"] == [{"id": 17, "reason": "unobserved"}]
    assert "left out robot 17: unobserved" in out.stderr
    robots = {r["id"]: r for r in doc["robots"]}
    assert sorted(robots) == [11, 12, 13, 14, 15, 16]
    assert robots[16]["heading"] is None  # 16 observed nobody in the example
    assert abs(robots[11]["x"]) < 0.01 and abs(robots[11]["y"]) < 0.01


def test_prior_gives_global_frame_and_resists_the_outlier():
    out = swarm("localize", str(EXAMPLES / "localize-prior.json"))
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    assert doc["frame"] == "global"
    robots = {r["id"]: r for r in doc["robots"]}
    # Robot 13's true position is (0.15, 0.30); the example holds a gross outlier about it.
    assert abs(robots[13]["x"] - 0.15) < 0.03 and abs(robots[13]["y"] - 0.30) < 0.03
    plain = json.loads(swarm("localize", str(EXAMPLES / "localize-prior.json"), "--no-robust").stdout.splitlines()[-1])
    plain13 = {r["id"]: r for r in plain["robots"]}[13]
    assert plain13["delta_p"] > robots[13]["delta_p"]


def test_strict_names_the_robot_that_cannot_be_localized():
    out = swarm("localize", str(EXAMPLES / "localize-topology.json"), "--strict")
    assert out.returncode == 2
    assert "unobserved: robots [17]" in out.stderr
    assert "Traceback" not in out.stderr


@pytest.mark.parametrize(
    "content,message",
    [
        ("{not json", "is not valid JSON"),
        ('{"robots": [1, 2], "observations": [[1, 2, NaN, 0.1]]}', "observations[0][2] (range_m): expected a finite number"),
        ('{"robots": [1, 2], "observations": [[1, 9, 0.2, 0.1]]}', "unknown robot ids in observations: [9]"),
        ('{"robots": [1, 2], "observations": [[1, 2, 0.2]]}', "observations[0]: expected [observer, observed, range_m, bearing_rad]"),
        ('{"robots": [1, 1], "observations": []}', "duplicate robot ids: [1]"),
        ('{"robots": [1, 2], "observations": [[1, 2, -0.2, 0.0]]}', "negative ranges"),
        ('{"robots": [1, 2], "observations": [[2, 1, 0.2, 0.0], [1, 2, 0.2, 3.1]], '
         '"prior": [{"id": 1, "x": 0, "y": 0, "heading": 0, "delta": 0.01, "sigma_heading": 0.1}]}', "missing [2]"),
    ],
)
def test_bad_input_gets_a_clear_error(tmp_path, content, message):
    path = tmp_path / "in.json"
    path.write_text(content)
    out = swarm("localize", str(path))
    assert out.returncode == 2
    assert message in out.stderr
    assert "Traceback" not in out.stderr


def test_missing_file_is_a_clear_error(tmp_path):
    out = swarm("localize", str(tmp_path / "nope.json"))
    assert out.returncode == 2 and "nope.json" in out.stderr and "Traceback" not in out.stderr


def test_bench_localize_json_contract():
    """The errors it prints are those of the same random steps localized here (seed + trial), to its 4 digits."""
    import math

    import numpy as np

    from coordinator.localization import make_localizer
    from inchworm.bench.localize import SPACING_M
    from runtime.models.config import ModelConfig
    from runtime.models.scenarios import random_step

    out = swarm("bench", "localize", "--sizes", "10,30", "--trials", "1", "--repeats", "1", "--no-gtsam", "--seed", "3", "--json")
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    assert [r["n"] for r in doc["results"]] == [10, 30]
    for r in doc["results"]:
        case = random_step(r["n"], ModelConfig(), np.random.default_rng(3), spacing=SPACING_M, seed=3)
        for name in BUILTIN_LOCALIZERS:
            est = make_localizer(name, ModelConfig()).localize(case.prior, case.step, case.observations)
            rms = math.sqrt(float(np.mean(np.sum((est.positions - case.true_after[:, :2]) ** 2, axis=1))))
            assert r[name]["err_rms_m"] == pytest.approx(rms, rel=1e-3), name
            assert r[name]["err_over_crlb"] == pytest.approx(r[name]["err_rms_m"] / r["crlb_rms_m"], rel=2e-3), name
        assert r["ms_median"] == r["paper"]["ms_median"] > 0 and r["err_over_crlb"] == r["paper"]["err_over_crlb"]
        assert r["joint"]["err_over_crlb"] < r["paper"]["err_over_crlb"]


def test_solver_failure_has_its_own_exit_code_and_localizes_the_rest(tmp_path):
    """Two robots at the same spot (0 mm, no prior): the joint topology does not converge with all of
    them (this draw); the robots it names are left out, the rest is localized, exit code 3."""
    from localize_cases import close_pair_case, document  # shared test scenario

    _, obs, _ = close_pair_case(6, 0.0, True, 11)
    path = tmp_path / "pair.json"
    path.write_text(json.dumps(document(obs, None, 6)))
    out = swarm("localize", str(path), "--localizer", "joint")
    assert out.returncode == 3, out.stderr
    doc = json.loads(out.stdout.strip().splitlines()[-1], parse_constant=lambda c: pytest.fail(f"invalid JSON constant {c}"))
    failed = [e["id"] for e in doc["excluded"] if e["reason"] == "no-convergence"]
    assert failed and {r["id"] for r in doc["robots"]} == set(range(6)) - set(failed)
    assert f"left out robot {failed[0]}: no-convergence" in out.stderr
    strict = swarm("localize", str(path), "--localizer", "joint", "--strict")
    assert strict.returncode == 3 and "no-convergence" in strict.stderr and "Traceback" not in strict.stderr
    assert strict.stdout.strip() == ""


def test_bench_localize_still_prior_gives_the_anchors_their_own_prior():
    """--still-prior: the robots that do not move start with that prior std; layout, movers and draws are unchanged."""
    import numpy as np

    from inchworm.bench.localize import SPACING_M
    from runtime.models.config import ModelConfig
    from runtime.models.scenarios import random_step

    plain = random_step(10, ModelConfig(), np.random.default_rng(3), spacing=SPACING_M, seed=3)
    precise = random_step(10, ModelConfig(), np.random.default_rng(3), spacing=SPACING_M, seed=3, still_delta=0.002)
    still = ~plain.step.moving
    np.testing.assert_array_equal(precise.step.moving, plain.step.moving)
    np.testing.assert_array_equal(precise.prior.poses, plain.prior.poses)
    np.testing.assert_allclose(precise.prior.cov[~still], plain.prior.cov[~still])
    np.testing.assert_allclose(precise.prior.cov[still, 0, 0], 0.002**2 / 2)
    assert np.all(np.linalg.norm(precise.true_before[still, :2] - precise.prior.poses[still, :2], axis=1) <
                  np.linalg.norm(plain.true_before[still, :2] - plain.prior.poses[still, :2], axis=1))
    out = swarm("bench", "localize", "--sizes", "10", "--trials", "1", "--repeats", "1", "--no-gtsam", "--seed", "3",
                "--still-prior", "0.002", "--json")
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    assert doc["still_prior_m"] == 0.002 and doc["results"][0]["joint"]["err_over_crlb"] < doc["results"][0]["paper"]["err_over_crlb"]
    bad = swarm("bench", "localize", "--still-prior", "0")
    assert bad.returncode == 2 and "--still-prior must be > 0 m" in bad.stderr


def test_one_way_sightings_far_ranges_and_a_duplicate(tmp_path):
    """Robot 3 sees 1 and 2 at 2 m (4x the default 0.5 m sensing range), nobody sees 3, and row 2 repeats
    row 0: every robot is localized (exit 0), 1 and 2 without a heading; stderr warns once per finding,
    naming the rows, and the JSON lists them."""
    path = tmp_path / "in.json"
    path.write_text('{"robots": [1, 2, 3], "observations": [[3, 1, 2.0, 0.5], [3, 2, 2.0, -0.7], [3, 1, 2.0, 0.5]]}')
    out = swarm("localize", str(path), "--json")
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    assert doc["excluded"] == [] and doc["reference"] == 3
    assert [(r["id"], r["heading"], r["sigma_heading"]) for r in doc["robots"][:2]] == [(1, None, None), (2, None, None)]
    assert doc["duplicates"] == [2] and doc["beyond_sensing_range"] == [0, 1, 2] and doc["suspects"] == []
    assert [o["used"] for o in doc["observations"]] == [True, True, False]
    assert out.stderr.splitlines() == [
        "swarm localize: warning: duplicated observation rows 2 (the same as an earlier row) are used once",
        "swarm localize: warning: observation rows 0, 1, 2 have ranges beyond the sensing range 0.5 m (+3 range sigmas): "
        "set --sensing-range (or --model FILE) to your sensor's",
    ]
