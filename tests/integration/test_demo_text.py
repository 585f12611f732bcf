"""What ``swarm demo`` prints about its choices is true of the run it makes (in-process: the distributed run
reproduces ``simulate`` for the same seed, docs/quickstart.md)."""

from __future__ import annotations

import pytest

from inchworm import simulate
from inchworm.simulation import anchor_choices
from swarm_cli.launch import PAPER_SCENARIO, PAPER_TEXT


@pytest.fixture(scope="module")
def paper_demo():
    """``swarm demo --paper``'s run: the built-in trajectory (10 robots, 3 configurations, seed 0), the paper's localizer."""
    return simulate(robots=10, configs=3, seed=0, localizer=PAPER_SCENARIO["localizer"])


def test_the_paper_announcement_holds_for_every_configuration(paper_demo) -> None:
    """``--paper`` announces n_a = 0 wherever moving every robot at once keeps the bodies apart, else the best-scoring
    count with a plan: each configuration's choice is one of the two."""
    assert "n_a = 0, wherever moving every robot at once keeps the bodies apart" in PAPER_TEXT
    for rec in paper_demo.configs:
        scores = {s.n_anchors: s for s in rec.selection.scores}
        if rec.plan.n_anchors != 0:
            assert scores[0].plan is None and scores[0].crowded, f"config {rec.config + 1}: anchors although n_a = 0 had a plan"
            best = max((s for s in scores.values() if s.plan is not None), key=lambda s: s.p_s)
            assert best.n_anchors == rec.plan.n_anchors
    assert len(paper_demo.configs) == 3  # every configuration was checked (with bodies kept apart at 1e-3 a pair and step,
    # moving every robot at once is crowded in all three here, so each takes the best count with a plan)


def test_counts_without_a_plan_are_one_line_per_reason(paper_demo) -> None:
    lines = anchor_choices(paper_demo)
    reasons = [line for line in lines if "no plan" in line]
    for rec in paper_demo.configs:
        unplanned = [s.n_anchors for s in rec.selection.scores if s.plan is None]
        block = lines[lines.index(next(x for x in lines if x.startswith(f"config {rec.config + 1}:"))):]
        if unplanned:
            summary = next(x for x in block if "no plan" in x)
            assert summary.split(":")[0].strip() == f"n_a = {', '.join(map(str, unplanned))}"
    assert len(reasons) == sum(any(s.plan is None for s in rec.selection.scores) for rec in paper_demo.configs)
    rows = [line for line in lines if line.lstrip("* ").split(" ")[0].isdigit()]
    assert all(len(row.split()) == 6 + row.startswith("  *") for row in rows)  # scored rows only: n_a steps e_l P_v P_l P_s
