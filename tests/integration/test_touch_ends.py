"""A step that leaves two robots touching ends its leg (``coordinator.legs.new_touches``, docs/bodies.md "A touch ends
the leg"): on a run at motion noise x5.58 where robot 8 drives into robot 4 (``swarm sim --robots 10 --configs 5
--seed 1 --method inchworm --localizer joint --turn-sigma-deg 16.74 --drive-sigma-frac 0.279``) the pair touches in
that step and the next, which parts it (the leg's 7 remaining steps stood it touching before); a coordinator that
takes the run over right before or after the cut ends bit for bit as the uninterrupted run; ``swarm replay --check``
recomputes the cut from the recorded estimates and refuses a recording whose leg messages disagree."""

from __future__ import annotations

import copy
import math
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest

from coordinator.checkpoint import RunState
from coordinator.executor import InchwormExecutor
from coordinator.localization import make_localizer
from coordinator.replay_check import RecordedRun, check, rebuild_run
from coordinator.simulate import initial_estimate
from coordinator.strategies import make_strategy
from inchworm.bench.collisions import scaled
from inchworm.bench.options import CollisionsBenchOptions
from inchworm.sim_options import SimOptions
from runtime.models.config import ModelConfig
from runtime.models.trajectory import body_spacing, random_trajectory
from runtime.wire.messages import MotionCommand, PlanMessage
from tests.integration.test_replay_chain import RecordingSwarm

X558 = ModelConfig(turn_sigma_rad=math.radians(16.74), drive_sigma_frac=0.279)
OPTIONS = SimOptions(robots=10, configs=5, seed=1, method="inchworm", localizer="joint", model=X558)


def execute(swarm, on_checkpoint=None, resume: RunState | None = None):
    o = OPTIONS
    traj = o.run_trajectory()
    loc = make_localizer(o.localizer, X558)
    strategy = make_strategy(o.method, traj.n, X558, loc, o.selection, o.seed)
    return InchwormExecutor(swarm, loc, strategy, X558, listener=swarm, on_checkpoint=on_checkpoint).run(
        traj, initial_estimate(traj, o.seed, o.initial_delta_m, o.initial_heading_sigma_rad), resume=resume)


def recording() -> RecordedRun:
    o = OPTIONS
    traj = o.run_trajectory()
    return RecordedRun(Path("memory"), {}, {"localizer": o.localizer, "method": o.method, "seed": o.seed,
                                            "trajectory": traj.to_json(), "initial_delta_m": o.initial_delta_m,
                                            "initial_heading_sigma_rad": o.initial_heading_sigma_rad,
                                            "model": X558.to_dict(), "selection": asdict(o.selection)})


@pytest.fixture(scope="module")
def clean():
    """The run, its recording, its checkpoints, and the robots as they were at each of the two checkpoints around the
    cut (a coordinator that dies there leaves them so: they outlive it)."""
    rec = recording()
    states: list[RunState] = []
    swarm = RecordingSwarm(OPTIONS.run_trajectory(), rec, None, X558, OPTIONS.seed)
    robots: dict[int, tuple[RecordingSwarm, str]] = {}
    last: list[tuple[RecordingSwarm, str]] = []

    def keep(state: RunState) -> None:  # the checkpoint as published then (its result grows with the run)
        states.append(state)
        swarm.rec = RecordedRun(Path("memory"), {}, {})  # the robots alone are copied
        last[:] = [*last[-1:], (copy.deepcopy(swarm), state.to_json())]
        swarm.rec = rec
        if state.legs and state.legs[-1].cut and not robots:
            robots[len(states) - 2], robots[len(states) - 1] = last
    return execute(swarm, keep), rec, states, robots


def test_a_touch_ends_the_leg_and_the_next_step_parts_the_pair(clean):
    result, rec, _, _ = clean
    assert [(c.step, c.a, c.b) for c in result.contacts(X558.robot_radius_m)] == [(119, 4, 8), (120, 4, 8)]
    config = result.configs[4]
    [(k, cut)] = [(k, leg) for k, leg in enumerate(config.legs) if leg.cut]
    assert cut.n_steps < cut.plan.n_steps and config.legs_cut == 1
    assert sum(c.n_steps for c in result.configs[:4]) + sum(leg.n_steps for leg in config.legs[:k + 1]) == 119  # ends at the touch
    assert sorted(result.steps[119].estimate.ids[result.steps[119].moving].tolist()) == [8]  # the next leg parts them
    assert len(result.steps) == sum(c.n_steps for c in result.configs) == result.steps_added() + sum(c.planned_steps for c in result.configs)
    nxt = config.legs[k + 1]
    not_run = cut.ids[~cut.ran]
    assert len(not_run) and np.isin(not_run, cut.going_on).all() and np.isin(not_run, np.union1d(nxt.ids, nxt.held)).all()
    # the recording rebuilt for plots follows the cut: the same steps in the same configurations
    rebuilt = rebuild_run(rec)
    assert rebuilt.steps_per_config().tolist() == result.steps_per_config().tolist()
    assert rebuilt.configs[4].legs[k].n_steps == cut.n_steps


def test_a_run_taken_over_right_before_or_after_the_cut_ends_bit_for_bit(clean):
    result, _, states, robots = clean
    after = max(robots)
    assert states[after].legs[-1].cut and states[after].group == states[after].legs[-1].n_steps and states[after].step == 119
    assert not states[after - 1].legs[-1].cut and states[after - 1].step == 118
    for k, (swarm, published) in sorted(robots.items()):
        taken = RunState.from_json(published, OPTIONS.run_trajectory(), result.initial_estimate)
        assert taken.to_json() == published
        swarm.rec = recording()
        resumed = execute(swarm, resume=taken)
        assert len(resumed.steps) == len(result.steps), k
        for a, b in zip(resumed.steps, result.steps, strict=True):
            np.testing.assert_array_equal(a.estimate.poses, b.estimate.poses)
            np.testing.assert_array_equal(a.truth, b.truth)
        assert [c.n_steps for c in resumed.configs] == [c.n_steps for c in result.configs]
        assert [[leg.groups_run for leg in c.legs] for c in resumed.configs] == [[leg.groups_run for leg in c.legs] for c in result.configs]


def test_replay_check_recomputes_the_cut_and_refuses_leg_messages_that_disagree(clean):
    _, rec, _, _ = clean
    checked = check(rec)
    assert checked.passed and checked.skipped == [], (checked.divergence, checked.skipped)
    (config, leg), msg = next(((key, m) for key, m in sorted(rec.legs.items()) if m.step == 120))
    late = replace(rec, legs={**rec.legs, (config, leg): PlanMessage(run="m", step=121, config=config, n_anchors=msg.n_anchors,
                                                                       groups=msg.groups, leg=leg)})
    bad = check(late)
    assert bad.divergence is not None and bad.divergence.step == 120, bad.divergence
    assert bad.divergence.field.startswith("groups (step 119 left robots 4 and 8 touching")
    early = replace(rec, legs={**rec.legs, (config, leg): PlanMessage(run="m", step=119, config=config, n_anchors=msg.n_anchors,
                                                                        groups=msg.groups, leg=leg)})
    bad = check(early)
    assert bad.divergence is not None and bad.divergence.step == 119 and bad.divergence.field.startswith("first step")
    assert (bad.divergence.recorded, bad.divergence.recomputed) == (119, 124)  # no touch before step 119: the leg runs on


def test_a_robot_whose_step_is_at_risk_stands_in_it_and_replay_check_recomputes_it():
    """Trajectory 30 of the collisions bench at x5.58 (heuristic-fixed, joint localizer): robot 6 drives in a leg's
    first step and ends 5 cm from robot 8's way instead of where the leg planned it; robot 8's step, next, is over the
    bound against it where the estimate now puts it (0.19). Robot 8 stands in that step (the others of its group
    drive) and drives in the next leg, planned from the new estimate: no contact (one, robots 6 and 8, when it drove);
    ``swarm replay --check`` recomputes it."""
    o = CollisionsBenchOptions()
    cfg = scaled(o.run.model, 5.58)
    traj = random_trajectory(o.robots, 6, np.random.default_rng([o.seed, 30]), sensing_range=cfg.sensing_range_m,
                             **body_spacing(cfg))
    seed = o.seed + 30
    rec = RecordedRun(Path("memory"), {}, {"localizer": "joint", "method": "heuristic-fixed", "seed": seed,
                                            "trajectory": traj.to_json(), "initial_delta_m": 0.01,
                                            "initial_heading_sigma_rad": math.radians(2.0), "model": cfg.to_dict(),
                                            "selection": asdict(o.run.selection)})
    swarm = RecordingSwarm(traj, rec, None, cfg, seed)
    loc = make_localizer("joint", cfg)
    strategy = make_strategy("heuristic-fixed", traj.n, cfg, loc, o.run.selection, seed)
    result = InchwormExecutor(swarm, loc, strategy, cfg, listener=swarm).run(traj, initial_estimate(traj, seed, 0.01, math.radians(2.0)))
    assert result.contacts(cfg.robot_radius_m) == []
    legs = result.configs[0].legs
    [(k, leg)] = [(k, leg) for k, leg in enumerate(legs) if len(leg.deferred)]
    assert leg.deferred.tolist() == [8] and not leg.cut and 6 in leg.ids[leg.ran]  # robot 6 drove in it, robot 8 stood
    assert 8 in np.union1d(legs[k + 1].ids, legs[k + 1].held)  # and goes on in the next
    checked = check(rec)
    assert checked.passed and checked.skipped == [], (checked.divergence, checked.skipped)
    stood = next(s for s in sorted(rec.commands) if set(rec.commands[s]) == {0, 2, 3, 4} and s > 1)  # robot 8's group, without it
    moved = {**rec.commands, stood: {**rec.commands[stood], 8: MotionCommand(run="m", step=stood, robot=8, config=1, turn_rad=0.3,
                                                                          drive_m=0.05)}}
    bad = check(replace(rec, commands=moved))
    assert bad.divergence is not None and bad.divergence.step == stood and bad.divergence.field.startswith("robots commanded")
