"""The chance constraint of bodies (docs/bodies.md): the contact probability bound of a pair over a step against a
Monte Carlo run of the true turn-then-drive motion, the bound being conservative, and the fallback where no order
keeps it."""

from __future__ import annotations

import numpy as np
import pytest

from coordinator.clearance import Regrouping, clear_plan
from coordinator.plan import Plan
from runtime.models.bodies import BOUND_LEVELS, CONTACT_BOUND, BodyCheck, closest_approach
from runtime.models.config import ModelConfig
from runtime.models.contact_risk import MotionMoments, disc_probability, instant_bound, step_bound
from runtime.models.motion import apply_motion, command_towards, draw_motion_noise
from runtime.models.state import SwarmEstimate

BASE = ModelConfig()
R = BASE.robot_radius_m


def noisy(scale: float) -> ModelConfig:
    return ModelConfig(turn_sigma_rad=BASE.turn_sigma_rad * scale, drive_sigma_frac=BASE.drive_sigma_frac * scale)


def correlated_joint(seed: int, scale: float = 0.004) -> np.ndarray:
    """A rough joint covariance of two poses: correlated positions and headings, anisotropic."""
    a = np.random.default_rng(seed).normal(size=(6, 6)) * scale
    return a @ a.T + np.diag([1e-5, 3e-5, 2e-3, 2e-5, 1e-5, 1e-3])


def bound_and_monte_carlo(cfg: ModelConfig, current: np.ndarray, desired: np.ndarray, joint: np.ndarray, moves: tuple[int, int],
                          fixed: tuple[int, int] = (0, 0), samples: int = 40_000) -> tuple[float, float]:
    """(the bound, the Monte Carlo frequency) of contact during a step of two robots starting at ``current`` (2, 2) with
    pose covariance ``joint`` (6, 6), each robot either standing before (``fixed`` 0) or after (1) its move to ``desired``,
    or making it in the step (``moves`` 1). The Monte Carlo draws the start poses, the turn and drive errors of the
    commands towards ``desired`` and checks the true relative segment against 2R, as ``step_contacts`` does."""
    moments = MotionMoments(cfg, current, desired, np.array([joint[:3, :3], joint[3:, 3:]]), joint)
    args = moments.pairs(np.array([0]), np.array([1]), np.array([fixed[0]]), np.array([moves[0]]), np.array([fixed[1]]), np.array([moves[1]]))
    bound = float(step_bound(*args, 2 * R, np.array([any(moves)]))[0])
    rng = np.random.default_rng(5)
    poses = np.column_stack([current, np.zeros(2)])
    start = rng.multivariate_normal(poses.ravel(), joint, samples).reshape(samples, 2, 3)
    turn, drive = draw_motion_noise(rng, (samples, 2), cfg)
    end = apply_motion(start, np.broadcast_to(command_towards(poses, desired), (samples, 2, 2)), turn, drive)
    at = [(end if fixed[k] else start)[:, k, :2] for k in range(2)]
    to = [end[:, k, :2] if (fixed[k] or moves[k]) else at[k] for k in range(2)]
    d = closest_approach(at[0] - at[1], (to[0] - at[0]) - (to[1] - at[1]))
    return bound, float(np.mean(d < 2 * R))


CASES = [  # (noise scale, current, desired, moves, fixed)
    (1.0, [[0.0, 0.0], [0.15, 0.05]], [[0.3, 0.0], [0.15, 0.05]], (1, 0), (0, 0)),  # a mover passing a still robot
    (3.0, [[0.0, 0.0], [0.15, -0.15]], [[0.3, 0.0], [0.15, 0.15]], (1, 1), (0, 0)),  # two movers crossing
    (3.0, [[0.0, 0.0], [0.0, 0.06]], [[0.3, 0.0], [0.3, 0.06]], (1, 1), (0, 0)),  # side by side
    (5.58, [[0.0, 0.0], [0.3, 0.15]], [[0.3, 0.0], [0.3, 0.15]], (1, 0), (0, 0)),  # arriving near a still robot
    (1.0, [[0.0, 0.0], [0.15, 2 * R]], [[0.3, 0.0], [0.15, 2 * R]], (1, 0), (0, 0)),  # the mean passes exactly at 2R
    (3.0, [[0.0, 0.0], [0.1, 0.0]], [[0.2, 0.1], [0.2, 0.13]], (0, 0), (1, 1)),  # still, left close by earlier moves
    (1.0, [[0.0, 0.0], [0.015, 0.0]], [[0.0, 0.0], [0.015, 0.0]], (0, 0), (0, 0)),  # still and already overlapping
]


@pytest.mark.parametrize("case", range(len(CASES)))
def test_the_bound_is_conservative_against_monte_carlo(case):
    scale, current, desired, moves, fixed = CASES[case]
    bound, frequency = bound_and_monte_carlo(noisy(scale), np.array(current), np.array(desired), correlated_joint(case), moves, fixed)
    error = 3.0 * np.sqrt(frequency * (1 - frequency) / 40_000) + 1e-4
    assert bound >= frequency - error  # conservative
    assert bound <= 1.0 and bound <= max(8.0 * frequency, 1e-3)  # and not uselessly loose
    if case == 4:
        assert 0.3 < frequency < 0.7 and bound >= 0.5  # half the passes at exactly 2R touch
    if case == 6:
        assert frequency > 0.3 and bound >= 0.5  # the mean inside the disc


def test_the_instant_bound_is_the_half_plane_of_the_mahalanobis_direction():
    """For a Gaussian r the bound of P(|r| < rho) is Phi(-g) of the best separating half-plane: with an isotropic
    covariance exactly Phi(-(|mu| - rho) / sigma), and conservative for a correlated anisotropic one."""
    from scipy.special import ndtr

    mu, sigma = np.array([[0.05, 0.02]]), 0.01
    got = instant_bound(mu, np.eye(2)[None] * sigma**2, 2 * R)
    assert got[0] == pytest.approx(ndtr(-(np.hypot(0.05, 0.02) - 2 * R) / sigma), rel=1e-12)
    cov = np.array([[[4e-4, -2.5e-4], [-2.5e-4, 2e-4]]])
    draws = np.random.default_rng(2).multivariate_normal(mu[0], cov[0], 200_000)
    exact = np.mean(np.hypot(*draws.T) < 2 * R)
    assert exact <= instant_bound(mu, cov, 2 * R)[0] <= 4 * exact


def test_the_disc_probability_of_one_instant_is_the_gaussians_and_at_most_the_bound():
    """``disc_probability`` (the approach legs' criterion) against draws of the Gaussian: correlated, anisotropic,
    near-degenerate covariances, means outside, at and inside the disc, all in one call; a covariance too narrow to
    integrate keeps the bound."""
    rho = 2 * R
    rng = np.random.default_rng(11)
    mus, covs = [], []
    for k, scale in enumerate((0.003, 0.008, 0.015, 0.03, 0.06, 0.012, 0.02)):
        a = rng.normal(size=(2, 2)) * scale
        cov = a @ a.T + np.eye(2) * 1e-9
        if k % 3 == 0:  # nearly one-dimensional
            cov = cov * np.array([[1.0, 0.999], [0.999, 1.0]])
        mus.append(rng.normal(size=2) * 0.04)
        covs.append(cov)
    mus += [[0.05, 0.03], [rho, 0.0], [0.005, -0.004], [0.1, 0.1]]  # around 1e-3, at the edge, inside, far away
    covs += [np.array([[1.5e-4, 4e-5], [4e-5, 1e-4]]), np.diag([4e-6, 1e-4]), np.diag([1e-4, 3e-5]), np.diag([1e-4, 1e-4])]
    mu, cov = np.array(mus), np.array(covs)
    got, bound = disc_probability(mu, cov, rho), instant_bound(mu, cov, rho)
    n = 400_000
    for k in range(len(mu)):
        freq = np.mean(np.hypot(*rng.multivariate_normal(mu[k], cov[k], n).T) < rho)
        assert abs(got[k] - freq) <= 4.0 * np.sqrt(freq * (1 - freq) / n) + 2e-5, (k, got[k], freq)
    assert np.all(got <= bound + 1e-12) and got[-4] == pytest.approx(2e-3, rel=0.2) and bound[-4] > 1.3 * got[-4]
    narrow = disc_probability(np.array([[rho, 0.0]]), np.diag([1e-8, 2e-8])[None], rho)  # sd 0.1-0.14 mm: the bound
    assert narrow[0] == instant_bound(np.array([[rho, 0.0]]), np.diag([1e-8, 2e-8])[None], rho)[0]
    assert disc_probability(np.zeros((0, 2)), np.zeros((0, 2, 2)), rho).shape == (0,)


def test_a_pass_is_allowed_at_a_distance_that_keeps_the_bound_and_the_uncertainty_needs_more():
    current = np.array([[0.0, 0.0], [0.15, 0.0]])
    moving = np.array([True, False])

    def conflicts(offset: float, position_var: float = 0.0) -> list:
        now = current + [[0.0, 0.0], [0.0, offset]]
        return BodyCheck(BASE, now, now + [[0.3, 0.0], [0.0, 0.0]], position_var).step_conflicts(now, moving)

    [near] = conflicts(0.04)  # 2.3 sigma of a 3 deg turn's swing at 0.15 m (7.9 mm), less 2R
    assert near.closest == pytest.approx(0.04) and near.allowed == CONTACT_BOUND and 0.01 < near.probability < 0.2
    assert conflicts(0.06) == []
    assert conflicts(0.06, position_var=0.005**2)  # the estimate's own uncertainty adds to the motion's
    assert BodyCheck(ModelConfig(robot_radius_m=0.0), current, current + 0.3).step_conflicts(current, np.array([True, True])) == []


def test_configurations_that_are_close_themselves_allow_their_own_risk():
    """Two robots whose desired positions are close (p_end above the bound): no order does better, so the step
    that brings the second one there is allowed twice that risk, not refused."""
    current = np.array([[0.0, 0.0], [0.0, 0.2]])
    desired = np.array([[0.3, 0.0], [0.3, 0.045]])
    check = BodyCheck(noisy(3.0), current, desired)
    moments = check.moments
    m0, _, c0, _, _ = moments.pairs(np.array([0]), np.array([1]), np.ones(1), np.zeros(1), np.ones(1), np.zeros(1))
    p_end = instant_bound(m0, c0, 2 * R)[0]
    assert p_end > CONTACT_BOUND
    for first in (0, 1):
        before = current.copy()
        before[first] = desired[first]
        moving = np.arange(2) != first
        for c in check.step_conflicts(before, moving):
            assert c.allowed == pytest.approx(2 * p_end)
    assert check.is_clear([np.array([0]), np.array([1])])


def test_where_no_order_keeps_the_bound_it_is_raised_and_then_robots_move_one_at_a_time_and_it_says_so():
    """Two robots trading places through a gap (each must pass where the other stands or arrives): no order keeps
    1e-3, the bound is raised for them, and if even the highest fails they move one at a time, named in the plan's
    description and in its --json record."""
    ids = np.array([4, 7, 9])
    poses = np.array([[0.0, 0.0, 0.0], [0.2, 0.006, 0.0], [1.0, 1.0, 0.0]])
    desired = np.array([[0.2, 0.0], [0.0, 0.006], [1.0, 1.1]])
    estimate = SwarmEstimate.isotropic(ids, poses, 0.003, 0.01)
    plan, regrouped = clear_plan(BASE, Plan.equal(np.arange(3), 0), estimate, desired)
    assert regrouped is not None and regrouped.bound == max(BOUND_LEVELS) and regrouped.unclear == (4, 7)
    assert [sorted(g.tolist()) for g in plan.groups].count([0]) == 1 and all(len(g) <= 2 for g in plan.groups)
    text = regrouped.describe(plan.n_steps)
    assert f"contact bound raised to {max(BOUND_LEVELS):g} per pair and step" in text and "robots [4, 7]" in text and "one at a time" in text
    assert regrouped.to_json(plan.n_steps) == {"planned_steps": 1, "steps": plan.n_steps, "contact_bound": max(BOUND_LEVELS), "unclear": [4, 7]}
    assert "raised" not in Regrouping(Plan.equal(np.arange(3), 0)).describe(2)
