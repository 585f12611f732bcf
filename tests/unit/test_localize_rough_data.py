"""``inchworm.localize`` on rough measured data, in process (the command as a user runs it: tests/system/test_cli_localize.py).

Rows are made from a known layout (headings near +-pi included) with seeded range/bearing noise, then
spoiled the ways real logs are: one-way sightings, a silent sensor, a robot seen by exactly one other,
a row attributed to the wrong robot, ranges several times the sensing range, duplicated rows.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import inchworm
from coordinator.localization.registry import BUILTIN_LOCALIZERS
from coordinator.localization.topology import to_reference_frame
from runtime.errors import LocalizationError, OptionError
from runtime.models.config import ModelConfig
from runtime.models.sensing import measure

CFG = ModelConfig(range_sigma_m=0.01, bearing_sigma_rad=math.radians(2.0), sensing_range_m=1.0)
# (x m, y m, heading rad) of robots 0..5: headings on both sides of the +-pi seam
LAYOUT = np.array([[0.0, 0.0, 0.3], [0.35, 0.05, 3.1], [0.15, 0.32, -3.1], [-0.25, 0.2, -1.2], [0.4, 0.4, 2.0], [-0.1, -0.3, 0.9]])


def rows(pairs: list[tuple[int, int]], seed: int = 0, layout: np.ndarray = LAYOUT, cfg: ModelConfig = CFG) -> list[list[float]]:
    """[observer, observed, range, bearing] of ``pairs`` with the sensor noise of ``cfg``."""
    rng = np.random.default_rng(seed)
    i, j = np.array(pairs).T
    rho, phi = measure(layout[i], layout[j, :2])
    rho = rho + rng.normal(0, cfg.range_sigma_m, len(i))
    phi = phi + rng.normal(0, cfg.bearing_sigma_rad, len(i))
    return [[int(a), int(b), float(r), float(p)] for a, b, r, p in zip(i, j, rho, phi, strict=True)]


def everyone(n: int = 6) -> list[tuple[int, int]]:
    return [(a, b) for a in range(n) for b in range(n) if a != b]


def local_truth(ref: int, layout: np.ndarray = LAYOUT) -> np.ndarray:
    return to_reference_frame(layout, layout[ref])


def by_id(doc: dict) -> dict[int, dict]:
    return {r["id"]: r for r in doc["robots"]}


@pytest.mark.parametrize("localizer", BUILTIN_LOCALIZERS)
def test_one_way_sightings_localize_everyone_and_leave_unseen_headings_unknown(localizer):
    """Robot 2 sees 0 and 1, nobody sees 2: all three are placed (2 is the reference); 0 and 1 have no
    heading (null, and sigma_heading null)."""
    doc = inchworm.localize({"robots": [0, 1, 2], "observations": rows([(2, 0), (2, 1)])}, CFG, localizer).to_json()
    assert doc["excluded"] == [] and doc["reference"] == 2
    robots, truth = by_id(doc), local_truth(2)
    for r in (0, 1):
        assert robots[r]["heading"] is None and robots[r]["sigma_heading"] is None
        assert math.hypot(robots[r]["x"] - truth[r, 0], robots[r]["y"] - truth[r, 1]) < 4 * robots[r]["delta_p"]
    assert robots[2]["heading"] == 0.0 and robots[2]["sigma_heading"] is not None


@pytest.mark.parametrize("localizer", BUILTIN_LOCALIZERS)
def test_a_silent_sensor_drops_nobody(localizer):
    """Robot 3's sensor is silent (it reports nothing) and robot 5 was seen only by 3: 5 saw 0 and 1, so it
    is placed all the same; 3 has a position and no heading."""
    pairs = [p for p in everyone() if p[0] != 3 and p[1] != 5]
    doc = inchworm.localize({"robots": list(range(6)), "observations": rows(pairs, seed=1)}, CFG, localizer).to_json()
    assert doc["excluded"] == []
    robots, truth = by_id(doc), local_truth(doc["reference"])
    assert robots[3]["heading"] is None and robots[5]["heading"] is not None
    for r in range(6):
        assert math.hypot(robots[r]["x"] - truth[r, 0], robots[r]["y"] - truth[r, 1]) < 0.05


@pytest.mark.parametrize("localizer", BUILTIN_LOCALIZERS)
def test_a_robot_seen_by_exactly_one_other(localizer):
    """0 <-> 1 <-> 2, and robot 4 (silent) seen by robot 1 only: placed through 1's pose, heading unknown."""
    pairs = [(0, 1), (1, 0), (1, 2), (2, 1), (1, 4)]
    doc = inchworm.localize({"robots": [0, 1, 2, 4], "observations": rows(pairs, seed=2)}, CFG, localizer).to_json()
    assert doc["excluded"] == []
    four, truth = by_id(doc)[4], local_truth(0)
    assert four["heading"] is None
    assert math.hypot(four["x"] - truth[4, 0], four["y"] - truth[4, 1]) < 0.05


def test_what_cannot_be_fixed_is_named_and_only_that():
    """0 <-> 1, 1 -> 2 -> 3: 2 is placed by 1, but 2's heading is free, so 3 is undetermined; 5 is in no row."""
    pairs = [(0, 1), (1, 0), (1, 2), (2, 3)]
    doc = inchworm.localize({"robots": [0, 1, 2, 3, 5], "observations": rows(pairs, seed=3)}, CFG).to_json()
    assert doc["excluded"] == [{"id": 3, "reason": "undetermined"}, {"id": 5, "reason": "unobserved"}]
    assert [r["id"] for r in doc["robots"]] == [0, 1, 2]
    assert [o["used"] for o in doc["observations"]] == [True, True, True, False]
    with pytest.raises(LocalizationError, match=r"^unobserved: robots \[5\] \(cannot be localized; also undetermined 3\)$"):
        inchworm.localize({"robots": [0, 1, 2, 3, 5], "observations": rows(pairs, seed=3)}, CFG, strict=True)


def test_options_and_keywords_localize_alike_and_bad_options_name_their_field():
    """``localize(LocalizeOptions(...))`` is ``localize(source, model, localizer, strict=..., robust=...)``; a bad value
    raises ``OptionError`` naming the field (the command line: its flag), both forms at once a ``TypeError``."""
    doc = {"robots": list(range(6)), "observations": rows([(a, b) for a in range(6) for b in range(6) if a != b], seed=4)}
    options = inchworm.LocalizeOptions(source=doc, model=CFG, localizer="joint", robust=False)
    assert inchworm.localize(options).to_json() == inchworm.localize(doc, CFG, "joint", robust=False).to_json()
    with pytest.raises(OptionError, match="^localizer must be a registered localizer's name, got 3$") as caught:
        inchworm.localize(doc, CFG, 3)
    assert caught.value.flag_message() == "--localizer must be a registered localizer's name, got 3"
    with pytest.raises(OptionError, match="^strict must be True or False, got 'yes'$") as caught:
        inchworm.localize(doc, strict="yes")
    assert caught.value.flag() == "--strict"
    with pytest.raises(OptionError) as caught:
        inchworm.LocalizeOptions(source=doc, robust=1)
    assert caught.value.flag() == "--no-robust"
    with pytest.raises(TypeError, match="not both"):
        inchworm.localize(options, strict=True)


@pytest.mark.parametrize("localizer", BUILTIN_LOCALIZERS)
def test_an_observation_of_the_wrong_robot_is_a_suspect(localizer):
    """Every pair observed; row 0 -> 1 is logged as 0 -> 4 (the measurement is of robot 1): that row is
    flagged, its chi-square far beyond the threshold and the largest. The joint localizer (least squares)
    flags nothing else; the paper's clusters are pulled a little, so one row of 30 is marginally over
    (12.4 > 11.83, measured). The estimate resists it."""
    pairs = everyone()
    data = rows(pairs, seed=4)
    wrong = pairs.index((0, 1))
    data[wrong][1] = 4
    doc = inchworm.localize({"robots": list(range(6)), "observations": data}, CFG, localizer).to_json()
    chi2 = [o["range_residual"] ** 2 + o["bearing_residual"] ** 2 for o in doc["observations"]]
    assert doc["suspects"] == ([wrong] if localizer == "joint" else [wrong, 8])
    assert doc["observations"][wrong]["suspect"] and chi2[wrong] == max(chi2) > 10 * doc["suspect_chi2"]
    assert any(w.startswith(f"suspect observation rows {wrong}") for w in doc["warnings"])
    truth = local_truth(0)
    for r in by_id(doc).values():
        assert math.hypot(r["x"] - truth[r["id"], 0], r["y"] - truth[r["id"], 1]) < 0.03


def test_clean_rows_have_unit_scale_residuals():
    """Residuals are whitened: with the noise the model assumes, their mean square is about 1 per axis
    (a little less: the fit absorbs some), and nothing is flagged."""
    doc = inchworm.localize({"robots": list(range(6)), "observations": rows(everyone(), seed=5)}, CFG, "joint").to_json()
    res = np.array([[o["range_residual"], o["bearing_residual"]] for o in doc["observations"]])
    assert 0.4 < np.mean(res**2) < 1.5 and doc["suspects"] == [] and doc["warnings"] == []


def test_ranges_beyond_the_sensing_range_are_warned():
    """The layout scaled 10x (ranges 2.5-8.6 m, 2.5-8.6x the 1 m sensing range): every row is named, and once
    the sensing range is set to the sensor's the warning is gone."""
    layout = LAYOUT * [10.0, 10.0, 1.0]
    data = rows(everyone(), seed=6, layout=layout)
    doc = inchworm.localize({"robots": list(range(6)), "observations": data}, CFG).to_json()
    assert doc["beyond_sensing_range"] == list(range(len(data))) and doc["sensing_range_m"] == 1.0
    warning = next(w for w in doc["warnings"] if "beyond the sensing range 1 m" in w)
    assert warning.startswith("observation rows 0, 1, 2, ") and f"({len(data)} in all)" in warning
    far = ModelConfig(range_sigma_m=0.01, bearing_sigma_rad=math.radians(2.0), sensing_range_m=9.0)
    assert inchworm.localize({"robots": list(range(6)), "observations": data}, far).checks["beyond_sensing_range"] == []


@pytest.mark.parametrize("localizer", BUILTIN_LOCALIZERS)
def test_duplicated_rows_are_used_once(localizer):
    """Rows 3 and 7 repeated at the end: named, unused, and the answer is the one without them (a row
    counted twice would shrink every delta_p)."""
    data = rows(everyone(), seed=7)
    once = inchworm.localize({"robots": list(range(6)), "observations": data}, CFG, localizer).to_json()
    twice = inchworm.localize({"robots": list(range(6)), "observations": [*data, data[3], data[7]]}, CFG, localizer).to_json()
    n = len(data)
    assert twice["duplicates"] == [n, n + 1] and once["duplicates"] == []
    assert [o["used"] for o in twice["observations"][n:]] == [False, False]
    assert twice["robots"] == once["robots"]
    assert any("duplicated observation rows" in w for w in twice["warnings"])


def test_with_a_prior_the_joint_localizer_places_what_the_topology_cannot():
    """0 <-> 1, 1 -> 2 -> 3 with a prior: the prior's heading of 2 fixes 3 for the joint localizer;
    the paper's topology ignores the prior's headings and leaves 3 out."""
    pairs = [(0, 1), (1, 0), (1, 2), (2, 3)]
    prior = [{"id": r, "x": LAYOUT[r, 0], "y": LAYOUT[r, 1], "heading": LAYOUT[r, 2], "delta": 0.05, "sigma_heading": 0.1} for r in range(4)]
    data = {"robots": [0, 1, 2, 3], "observations": rows(pairs, seed=8), "prior": prior}
    assert inchworm.localize(data, CFG, "joint").excluded == {}
    assert inchworm.localize(data, CFG, "paper").excluded == {3: "undetermined"}
