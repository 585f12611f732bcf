"""Known answers for the batched localizer's input checks and linear-algebra helpers
(coordinator/localization/batch.py); its results against the single-swarm localizers are in
tests/unit/test_localization_batch.py.

Each case is constructed so the answer is known without the code: which sample holds an invalid
value, the solution of a diagonal system, the inverse of a covariance.
"""

from __future__ import annotations

import numpy as np
import pytest

import coordinator.localization.sparse_lm as sparse_lm
from coordinator.localization import make_localizer
from coordinator.localization.batch import (
    JOINT_TOL,
    _diagonal,
    _inv_stack,
    _JointProblem,
    _solve_chunks,
    _solve_stack,
    _valid,
    _Workspace,
    localize_batch,
    observable,
)
from coordinator.localization.dead_reckoning import dead_reckon_arrays, exact_moments
from coordinator.localization.range_bearing import prior_information, sqrt_information
from coordinator.localization.registry import BUILTIN_LOCALIZERS
from coordinator.localization.sparse_lm import COMPACT_BELOW, MAX_ITER, BatchOps, drive
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig

CFG = ModelConfig()


def triangle_batch(b: int):
    """``b`` identical samples: 3 robots on a 0.3 m triangle, everyone observes everyone with the exact
    range and bearing (headings 0), robot 0 moves 0.1 m; all values valid."""
    poses = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.15, 0.26, 0.0]])
    d = poses[None, :, :2] - poses[:, None, :2]
    ranges = np.hypot(d[..., 0], d[..., 1])
    bearings = np.arctan2(d[..., 1], d[..., 0])
    seen = ~np.eye(3, dtype=bool)
    commands = np.array([[0.0, 0.1], [0.0, 0.0], [0.0, 0.0]])
    moving = np.array([True, False, False])
    cov = np.broadcast_to(np.diag([1e-4, 1e-4, 1e-3]), (3, 3, 3))
    return [np.repeat(a[None], b, axis=0) for a in (poses, cov, commands, moving, seen, ranges, bearings)]


def driven_x(localizer, cov: np.ndarray, drive: float) -> float:
    """x of the dead reckoning of a robot at the origin, heading 0, covariance ``cov``, after driving ``drive`` m:
    ``drive`` for the paper's first order, ``drive`` exp(-s^2 / 2) (s^2 = heading variance + turn variance) for the
    joint localizer's exact mean."""
    x, _ = dead_reckon_arrays(np.zeros((1, 3)), cov[None], np.array([[0.0, drive]]), np.ones(1, bool), CFG, exact_moments(localizer))
    want = drive * np.exp(-(cov[2, 2] + CFG.turn_sigma_rad**2) / 2) if exact_moments(localizer) else drive
    assert x[0, 0] == pytest.approx(want, rel=1e-14)
    return float(x[0, 0])


@pytest.mark.parametrize("method", BUILTIN_LOCALIZERS)
def test_invalid_values_flag_only_their_sample(method):
    """Sample k gets one bad value each: 1 NaN pose, 2 infinite covariance, 3 NaN command of a moving
    robot, 4 negative drive of a moving robot, 5 negative range, 6 infinite range, 7 NaN bearing (all on
    seen pairs). Samples 0, 8 (NaN command and negative drive of a robot that does not move: ignored)
    and 9 (NaN range of an unseen pair) stay valid. Invalid samples are dead reckoning: the prior
    moved by the commands."""
    poses, cov, commands, moving, seen, ranges, bearings = triangle_batch(10)
    cov = cov.copy()
    poses[1, 2, 0] = np.nan
    cov[2, 1, 0, 0] = np.inf
    commands[3, 0, 0] = np.nan
    commands[4, 0, 1] = -0.1
    ranges[5, 0, 1] = -0.3
    ranges[6, 1, 2] = np.inf
    bearings[7, 2, 0] = np.nan
    commands[8, 1] = [np.nan, -1.0]  # robot 1 does not move
    seen[9, 0, 1] = False
    ranges[9, 0, 1] = np.nan
    with np.errstate(invalid="ignore"):  # dead reckoning of the NaN sample propagates NaN
        out = localize_batch(make_localizer(method, CFG), CFG, poses, cov, commands, moving, seen, ranges, bearings)
    assert out.ok.tolist() == [True, False, False, False, False, False, False, False, True, True]
    driven = driven_x(make_localizer(method, CFG), cov[0, 0], 0.1)
    for k in (5, 6, 7):  # invalid observations: dead reckoning, robot 0 driven 0.1 m along x
        np.testing.assert_allclose(out.poses[k, 0], [driven, 0.0, 0.0], atol=1e-12)
        np.testing.assert_allclose(out.poses[k, 1:], poses[k, 1:], atol=0)
    np.testing.assert_array_equal(out.poses[8], out.poses[0])


def test_no_robots_gives_empty_estimates():
    """n = 0: nothing to localize; every sample is ok and the arrays have shape (B, 0, ...)."""
    out = localize_batch(make_localizer("joint", CFG), CFG, np.zeros((2, 0, 3)), np.zeros((2, 0, 3, 3)), np.zeros((2, 0, 2)),
                         np.zeros((2, 0), bool), np.zeros((2, 0, 0), bool), np.zeros((2, 0, 0)), np.zeros((2, 0, 0)))
    assert out.ok.tolist() == [True, True] and out.ok.dtype == bool
    assert out.poses.shape == (2, 0, 3) and out.cov.shape == (2, 0, 3, 3)


def test_shapes_are_checked_with_their_names():
    """Every argument's shape is checked against (B, n, ...) and named in the message."""
    arrays = triangle_batch(2)
    names = ["prior_poses", "prior_cov", "commands", "moving", "seen", "ranges", "bearings"]
    for k, name in enumerate(names):
        bad = list(arrays)
        bad[k] = arrays[k][:, :2] if k else arrays[k][..., :2]
        with pytest.raises(SwarmInputError, match=f"{name} must have shape"):
            localize_batch(make_localizer("paper", CFG), CFG, *bad)
    with pytest.raises(SwarmInputError, match=r"prior_poses must have shape \(B, n, 3\), got \(3, 3\)"):
        localize_batch(make_localizer("paper", CFG), CFG, arrays[0][0], *arrays[1:])


def test_the_diagonal_of_seen_is_ignored():
    """A robot 'observing itself' (seen[b, i, i] with any value) changes nothing."""
    arrays = triangle_batch(1)
    base = localize_batch(make_localizer("joint", CFG), CFG, *arrays)
    seen, ranges = arrays[4].copy(), arrays[5].copy()
    seen[0, 1, 1], ranges[0, 1, 1] = True, 5.0
    out = localize_batch(make_localizer("joint", CFG), CFG, *arrays[:4], seen, ranges, arrays[6])
    assert out.ok.tolist() == [True]
    np.testing.assert_array_equal(out.poses, base.poses)


def test_observable_by_hand():
    """Three 3-robot samples: a ring (observable), robot 2 unobserved, and 0 <-> 1 with 2 -> 2 only
    (robot 2 unobserved by others). Observed-but-disconnected needs 4 robots: 0 <-> 1, 2 <-> 3."""
    seen = np.zeros((3, 3, 3), bool)
    seen[0, [0, 1, 2], [1, 2, 0]] = True
    seen[1, [0, 1, 2], [1, 0, 1]] = True
    seen[2, [0, 1], [1, 0]] = True
    assert observable(seen).tolist() == [True, False, False]
    four = np.zeros((2, 4, 4), bool)
    four[:, [0, 1, 2, 3], [1, 0, 3, 2]] = True
    four[1, 1, 2] = True  # one bridge connects the pairs
    assert observable(four).tolist() == [False, True]
    chain = np.zeros((1, 6, 6), bool)  # a path 5 -> 4 -> ... -> 0 plus 0 -> 5: needs the full search depth
    chain[0, [5, 4, 3, 2, 1, 0], [4, 3, 2, 1, 0, 5]] = True
    assert observable(chain).tolist() == [True]


def test_solve_stack_marks_singular_samples_with_nan():
    """diag(2, 4) x = (2, 4) gives x = (1, 1); a zero matrix has no solution: NaN, the others unaffected; the same with
    several right-hand sides a sample."""
    a = np.stack([np.diag([2.0, 4.0]), np.zeros((2, 2)), np.diag([1.0, 0.5])])
    rhs = np.array([[2.0, 4.0], [1.0, 1.0], [3.0, 1.0]])
    out = _solve_stack(a, rhs)
    np.testing.assert_allclose(out[[0, 2]], [[1, 1], [3, 2]])
    assert np.isnan(out[1]).all()
    np.testing.assert_allclose(_solve_stack(a[[0, 2]], rhs[[0, 2]]), [[1, 1], [3, 2]])
    columns = np.stack([rhs, 2 * rhs], axis=2)  # two right-hand sides a sample: (3, 2, 2)
    many = _solve_stack(a, columns)
    assert many.shape == (3, 2, 2)
    np.testing.assert_allclose(many[[0, 2]], [[[1, 2], [1, 2]], [[3, 6], [2, 4]]])
    assert np.isnan(many[1]).all()


def test_inv_stack_marks_singular_matrices_with_nan():
    """inv(diag(2, 4)) = diag(1/2, 1/4); [[1, 2], [2, 4]] is singular: NaN."""
    a = np.stack([np.diag([2.0, 4.0]), np.array([[1.0, 2.0], [2.0, 4.0]])])
    out = _inv_stack(a)
    np.testing.assert_allclose(out[0], np.diag([0.5, 0.25]))
    assert np.isnan(out[1]).all()


def test_prior_information_is_the_floored_inverse():
    """For a clearly positive definite covariance: its inverse. For a singular one (an exact prior) and an
    indefinite one: W^T W of ``sqrt_information`` (eigenvalues floored at 1e-12): diag(0, 0, 4) gives
    diag(1e12, 1e12, 1/4), diag(1, -1, 4) gives diag(1, 1e12, 1/4). An asymmetric input is symmetrised."""
    spd = np.array([[2.0, 0.3, 0.1], [0.3, 1.0, -0.2], [0.1, -0.2, 0.5]])
    skew = np.array([[0, 0.05, 0], [-0.05, 0, 0], [0, 0, 0]])
    cov = np.stack([spd, np.diag([0.0, 0.0, 4.0]), np.diag([1.0, -1.0, 4.0]), spd + skew])
    info = prior_information(cov)
    np.testing.assert_allclose(info[0], np.linalg.inv(spd), rtol=1e-12)
    np.testing.assert_allclose(info[1], np.diag([1e12, 1e12, 0.25]), rtol=1e-9)
    np.testing.assert_allclose(info[2], np.diag([1.0, 1e12, 0.25]), rtol=1e-9)
    np.testing.assert_allclose(info[3], np.linalg.inv(spd), rtol=1e-12)
    w = sqrt_information(cov)
    np.testing.assert_allclose(info, np.swapaxes(w, -1, -2) @ w, rtol=1e-9)
    np.testing.assert_array_equal(info, np.swapaxes(info, -1, -2))


@pytest.mark.parametrize("diagonal", [(-1.0, -1.0, 1.0), (1.0, -1.0, -1.0), (1.0, 1.0, -1.0)])
def test_prior_information_checks_every_leading_minor(diagonal):
    """Sylvester's criterion needs all three leading minors positive. Each of these diagonal covariances
    fails exactly one: diag(-1, -1, 1) the first (minors -1, 1, 1), diag(1, -1, -1) the second (1, -1, 1),
    diag(1, 1, -1) the determinant (1, 1, -1); so each is inverted with its negative eigenvalues floored
    at 1e-12 (information 1e12), not plainly (information -1)."""
    want = np.diag([1.0 if v > 0 else 1e12 for v in diagonal])
    np.testing.assert_allclose(prior_information(np.diag(diagonal)[None])[0], want, rtol=1e-9)


def test_diagonal_is_a_writable_view():
    """The diagonals of a (2, 3, 3) stack, and of a column slice of a (1, 2, 4) stack."""
    a = np.arange(18.0).reshape(2, 3, 3)
    np.testing.assert_array_equal(_diagonal(a), [[0, 4, 8], [9, 13, 17]])
    _diagonal(a)[:] = -1
    assert a[1, 2, 2] == -1 and a[1, 2, 1] == 16
    b = np.zeros((1, 2, 4))
    _diagonal(b[:, :, 2:])[:] = 7
    np.testing.assert_array_equal(b[0], [[0, 0, 7, 0], [0, 0, 0, 7]])


def test_workspace_reuses_arrays_of_the_same_shape():
    """The same name and shape returns the same array; another shape a new one."""
    ws = _Workspace()
    a = ws("x", (2, 3))
    assert ws("x", (2, 3)) is a
    b = ws("x", (3, 2))
    assert b is not a and b.shape == (3, 2) and ws("x", (3, 2)) is b


# --------------------------------------------------------------------------------------------
# The batched Levenberg-Marquardt on toy problems whose every step is known


class ToyProblem:
    """Samples of one robot whose cost is ``costs[s](x)`` (x the sample's (1, 3) pose) and whose step is the
    fixed ``steps[s]`` (1, 3) whatever the damping, with predicted decrease ``predicted[s]`` (default inf:
    never settles by ptol); every ``step`` call logs (samples, mu, curved)."""

    def __init__(self, costs, steps, log, index=None, predicted=None):
        self.costs, self.steps, self.log = costs, np.asarray(steps, float), log
        self.index = np.arange(len(costs)) if index is None else index
        self.predicted = np.full(len(costs), np.inf) if predicted is None else np.asarray(predicted, float)

    def evaluate(self, x, slot=0):
        return {"cost": np.array([self.costs[s](x[k]) for k, s in enumerate(self.index)])}

    def step(self, st, mu, curved):
        self.log.append((self.index.copy(), mu.copy(), curved.copy()))
        return self.steps[self.index].copy(), self.predicted[self.index].copy()

    def subset(self, keep):
        return ToyProblem(self.costs, self.steps, self.log, self.index[keep], self.predicted)


def run_toy(costs, steps, x0, xtol=1e-8, ftol=1e-8, ptol=None, predicted=None):
    log = []
    problem = ToyProblem(costs, steps, log, predicted=predicted)
    x, converged, _, _ = drive(problem, np.asarray(x0, float), xtol, ftol, ptol, xp=BatchOps)
    return x, converged, log


def test_lm_settles_a_sample_whose_step_predicts_no_gain(monkeypatch):
    """ptol = 1e-6, both samples' cost 1 everywhere and step +0.1 in x: sample 0's step predicts 1e-9 (below
    1e-6 x cost 1) and it settles where it is (x = 3, converged, no step taken); sample 1's predicts 1.0, so it
    takes its step (accepted: the cost does not rise), then converges on the zero cost decrease (x = 1.1)."""
    costs = [lambda x: 1.0, lambda x: 1.0]
    steps = [[[0.1, 0.0, 0.0]], [[0.1, 0.0, 0.0]]]
    x0 = [[[3.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]]]
    x, converged, log = run_toy(costs, steps, x0, ptol=1e-6, predicted=[1e-9, 1.0])
    assert converged.tolist() == [True, True]
    assert x[:, 0, 0].tolist() == [3.0, 1.1]
    x, converged, _ = run_toy(costs, steps, x0, ptol=None, predicted=[1e-9, 1.0])  # without ptol: both step
    assert converged.tolist() == [True, True] and x[:, 0, 0].tolist() == [3.1, 1.1]
    monkeypatch.setattr(sparse_lm, "PRED_MU_MAX", 1e-13)  # damping never negligible: ptol never settles
    x, _, _ = run_toy(costs, steps, x0, ptol=1e-6, predicted=[1e-9, 1.0])
    assert x[:, 0, 0].tolist() == [3.1, 1.1]


def test_lm_gives_up_when_mu_passes_1e10():
    """Every step raises the cost 0.5 |x|^2 from x = 0 (a step of 1 m, not negligible): each is rejected and
    mu grows tenfold from 1e-8: 1e-8, 1e-7, ..., 1e10 after 18 rejections (exactly 1e10 in floating point,
    not beyond it), so a 19th step is tried; it takes mu to 1e11 > 1e10: the sample fails at its start."""
    x, converged, log = run_toy([lambda p: 0.5 * float(np.sum(p**2))], [[[1.0, 0.0, 0.0]]], np.zeros((1, 1, 3)))
    mus = [float(mu[0]) for _, mu, _ in log]
    assert len(mus) == 19
    want = [1e-8]
    for _ in range(18):
        want.append(want[-1] * 10.0)
    assert mus == want and want[18] == 1e10
    assert not any(curved[0] for _, _, curved in log)  # no accepted step: Gauss-Newton throughout
    assert converged.tolist() == [False]
    np.testing.assert_array_equal(x, 0.0)


def test_lm_stops_after_max_iter_accepted_steps():
    """The cost 1e6 - x falls by 1 on every 1 m step along x: each step is accepted, none is small relative to
    x (xtol 1e-8) or to the cost (ftol 1e-8: 1 > 1e-2); after MAX_ITER = 100 accepted steps the sample
    fails at x = 100. mu falls tenfold per accepted step to its floor 1e-12; the first step is Gauss-Newton
    (curved False), the others carry the second-order term."""
    assert MAX_ITER == 100
    x, converged, log = run_toy([lambda p: 1e6 - p[0, 0]], [[[1.0, 0.0, 0.0]]], np.zeros((1, 1, 3)))
    assert len(log) == 100
    assert converged.tolist() == [False]
    np.testing.assert_array_equal(x[0, 0], [100.0, 0.0, 0.0])
    mus = [float(mu[0]) for _, mu, _ in log]
    np.testing.assert_allclose(mus[:5], [1e-8, 1e-9, 1e-10, 1e-11, 1e-12], rtol=1e-12)
    assert set(mus[5:]) == {1e-12}  # the floor, exactly
    assert [bool(c[0]) for _, _, c in log] == [False] + [True] * 99


@pytest.mark.parametrize(("rise", "accepted"), [(0.5e-12, True), ((1 + 1e-12) - 1.0, True), (2e-12, False)])
def test_lm_accepts_a_cost_rise_within_the_relative_slack(rise, accepted):
    """Cost 1 + rise x from x = 0, step 1: a rise of 0.5e-12 is within the relative slack 1e-12 and is
    accepted; the cost did not fall, so the sample converges there (x = 1). A rise to exactly the bound
    1 (1 + 1e-12) (floating point: 1 + ((1 + 1e-12) - 1) is that number) is accepted too (<=). A rise of
    2e-12 is rejected every time (mu grows until the sample fails at x = 0)."""
    x, converged, log = run_toy([lambda p: 1.0 + rise * p[0, 0]], [[[1.0, 0.0, 0.0]]], np.zeros((1, 1, 3)))
    assert converged.tolist() == [accepted]
    assert x[0, 0, 0] == (1.0 if accepted else 0.0)
    assert len(log) == (1 if accepted else 19)


def test_lm_converges_on_a_small_step_relative_to_x():
    """Robots at x = 1000 (the largest coordinate of the sample) step 1e-6 m, cost 10 - 1e-3 * step count
    (gain 1e-3, above ftol = 1e-20 x cost): 1e-6 <= xtol (1 + 1000) = 1.001e-5 with xtol = 1e-8, so the
    first accepted step converges. A sample at the origin taking the same step is not small (1e-6 > 1e-8)
    and runs to MAX_ITER, as does a step of 1.5e-8 from the origin (above xtol (1 + 0) = 1e-8)."""
    costs = [lambda p: 10.0 - 1e3 * (p[0, 0] - 1000.0), lambda p: 10.0 - 1e3 * p[0, 0], lambda p: 10.0 - 1e6 * p[0, 0]]
    x0 = np.zeros((3, 1, 3))
    x0[0, 0, 1] = 1000.0  # the largest |coordinate| of sample 0 (y), not the stepped one
    steps = [[[1e-6, 0, 0]], [[1e-6, 0, 0]], [[1.5e-8, 0, 0]]]
    x, converged, log = run_toy(costs, steps, x0, xtol=1e-8, ftol=1e-20)
    assert converged.tolist() == [True, False, False]  # sample 2: 1.5e-8 > xtol (1 + 0) near the origin
    np.testing.assert_allclose(x[:, 0, 0], [1e-6, 100 * 1e-6, 100 * 1.5e-8], rtol=1e-12)
    assert x[0, 0, 1] == 1000.0


@pytest.mark.parametrize(("ftol", "converged_at"), [(2e-3, 1.0), (5e-4, None)])
def test_lm_converges_on_a_small_cost_decrease(ftol, converged_at):
    """Cost 1 - 1e-3 x, steps of 1 (never small against xtol 1e-12): the first step lowers the cost by 1e-3,
    below ftol = 2e-3 times the cost 1: converged at x = 1. With ftol = 5e-4 no decrease is small
    (1e-3 > 5e-4 x cost) and the sample fails after MAX_ITER steps at x = 100."""
    x, converged, _ = run_toy([lambda p: 1.0 - 1e-3 * p[0, 0]], [[[1.0, 0, 0]]], np.zeros((1, 1, 3)), xtol=1e-12, ftol=ftol)
    assert converged.tolist() == [converged_at is not None]
    assert x[0, 0, 0] == (converged_at if converged_at is not None else 100.0)


def test_lm_a_negligible_rejected_step_means_converged():
    """At the minimum of 0.5 |x - 5|^2 (x = 5) a step of 1e-12 raises the cost and is rejected, but it is
    below xtol (1 + 5): the sample sits at its minimum and has converged, at x = 5 unchanged.
    A rejected step of 1 m is not negligible: mu grows and that sample fails."""
    costs = [lambda p: 0.5 * float(np.sum((p - 5.0) ** 2))] * 2
    x, converged, log = run_toy(costs, [[[1e-12, 0, 0]], [[1.0, 0, 0]]], np.full((2, 1, 3), 5.0))
    assert converged.tolist() == [True, False]
    np.testing.assert_array_equal(x, 5.0)


def test_lm_finished_samples_leave_the_work_set():
    """Five samples: four converge on their first step (x = 1, a gain below ftol), one runs MAX_ITER steps.
    Once fewer than COMPACT_BELOW = half of the work set is active the problem is restricted to sample 4:
    its later steps are asked of it alone, with its own mu and iteration count. Sample 2 has a NaN cost at
    its start: it never steps and keeps x0. Every sample ends where its own run would."""
    assert COMPACT_BELOW == 0.5
    flat = lambda p: 1.0 - 1e-12 * p[0, 0]  # noqa: E731  (converges on its first step)
    costs = [flat, flat, lambda p: np.nan, flat, lambda p: 1e6 - p[0, 0]]
    steps = [[[1.0, 0.0, 0.0]]] * 5
    x0 = np.arange(15.0).reshape(5, 1, 3)
    x, converged, log = run_toy(costs, steps, x0)
    assert converged.tolist() == [True, True, False, True, False]
    want = x0.copy()
    want[[0, 1, 3], 0, 0] += 1.0
    want[4, 0, 0] += 100.0
    np.testing.assert_array_equal(x, want)
    assert log[0][0].tolist() == [0, 1, 2, 3, 4]  # the first step: the whole work set (sample 2 masked)
    assert all(index.tolist() == [4] for index, _, _ in log[1:]) and len(log) == 100
    assert float(log[1][1][0]) == 1e-9 and bool(log[1][2][0])  # its own mu and iteration count survive
    assert float(log[-1][1][0]) == 1e-12


def test_lm_evaluates_no_trial_point_for_samples_a_step_settled():
    """Four samples of cost 1 everywhere, step +0.1: the first step of samples 0-2 predicts 1e-9 (below ptol x cost),
    sample 3's 1.0. Fewer than COMPACT_BELOW of the work set are then active, so the work set is sample 3 before its
    trial point is evaluated: the evaluations are the start (all four) and sample 3's trial alone; each sample ends
    where it would without the compaction (0-2 where they started, 3 one step on)."""
    evaluated = []

    class Logged(ToyProblem):
        def evaluate(self, x, slot=0):
            evaluated.append(self.index.tolist())
            return super().evaluate(x, slot)

        def subset(self, keep):
            return Logged(self.costs, self.steps, self.log, self.index[keep], self.predicted)

    costs = [lambda x: 1.0] * 4
    steps = [[[0.1, 0.0, 0.0]]] * 4
    x0 = np.arange(12.0).reshape(4, 1, 3)
    x, converged, _, _ = drive(Logged(costs, steps, [], predicted=[1e-9, 1e-9, 1e-9, 1.0]), x0, 1e-8, 1e-8, 1e-6, xp=BatchOps)
    assert evaluated == [[0, 1, 2, 3], [3]]
    assert converged.tolist() == [True] * 4
    want = x0.copy()
    want[3, 0, 0] += 0.1
    np.testing.assert_array_equal(x, want)


class ScalarToy:
    """Sample ``s`` of a ``ToyProblem`` as one problem for ``drive`` with ``ScalarOps`` (floats, a (1, 3) x)."""

    def __init__(self, toy, s):
        self.toy, self.s = toy, s

    def evaluate(self, x, slot=0):
        return {"cost": float(self.toy.costs[self.s](x))}

    def step(self, st, mu, curved):
        self.toy.log.append((np.array([self.s]), np.array([mu]), np.array([curved])))
        return self.toy.steps[self.s].copy(), float(self.toy.predicted[self.s])


def test_one_driver_for_one_problem_and_for_the_batch():
    """``drive`` with ``ScalarOps`` (one problem, floats: ``minimize``) takes each sample through the same trials as
    with ``BatchOps`` (the batch): the same points, convergence, damping and curvature flags, trial by trial. The
    samples: a rejected first step then convergence, a settled one (ptol), one that gives up, one at MAX_ITER."""
    costs = [lambda p: 0.5 * float(np.sum((p - 5.0) ** 2)), lambda p: 1.0, lambda p: 0.5 * float(np.sum(p**2)), lambda p: 1e6 - p[0, 0]]
    steps = [[[1e-12, 0, 0]], [[0.1, 0, 0]], [[1.0, 0, 0]], [[1.0, 0, 0]]]
    x0 = np.zeros((4, 1, 3))
    x0[0] = 5.0
    predicted = [np.inf, 1e-9, np.inf, np.inf]
    x, converged, log = run_toy(costs, steps, x0, ptol=1e-6, predicted=predicted)
    assert converged.tolist() == [True, True, False, False]
    for s in range(4):
        toy = ToyProblem(costs, steps, [], predicted=predicted)
        one_x, one_converged, iterations, _ = drive(ScalarToy(toy, s), x0[s], 1e-8, 1e-8, 1e-6, xp=sparse_lm.ScalarOps)
        np.testing.assert_array_equal(one_x, x[s])
        assert one_converged == converged[s]
        batch_trials = [(float(mu[list(index).index(s)]), bool(curved[list(index).index(s)])) for index, mu, curved in log if s in index]
        assert [(float(mu[0]), bool(c[0])) for _, mu, c in toy.log] == batch_trials[: len(toy.log)]
        assert iterations >= 1


def test_prior_information_of_a_correlated_singular_covariance():
    """cov = [[1, 0, 0.5], [0, 1, 0], [0.5, 0, 0.25]] (x and heading perfectly correlated) is singular: its
    eigenvectors u = (1, 0, -2)/sqrt(5), e_y, w = (2, 0, 1)/sqrt(5) have eigenvalues 0, 1, 1.25. Its leading
    minors 1 and 1 are positive, only the determinant (0) shows it is not clearly positive definite; the
    floored inverse is 1e12 u u^T + e_y e_y^T + w w^T / 1.25."""
    cov = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.0], [0.5, 0.0, 0.25]])
    u, w = np.array([1.0, 0.0, -2.0]) / np.sqrt(5), np.array([2.0, 0.0, 1.0]) / np.sqrt(5)
    want = 1e12 * np.outer(u, u) + np.diag([0.0, 1.0, 0.0]) + np.outer(w, w) / 1.25
    info = prior_information(cov[None])[0]
    np.testing.assert_allclose(info, want, rtol=1e-6, atol=1e-3)


def test_a_zero_range_is_a_valid_observation():
    """Ranges must be >= 0 and finite: a measured range of exactly 0 m (robots touching) is valid, -0.1 m and
    an infinite range are not; a bad value on an unseen pair does not count."""
    poses, cov, commands, moving, seen, ranges, bearings = triangle_batch(4)
    ranges = ranges.copy()
    ranges[0, 0, 1] = 0.0
    ranges[1, 0, 1] = -0.1
    ranges[2, 0, 1] = np.inf
    seen = seen.copy()
    seen[3, 0, 1], ranges[3, 0, 1] = False, -0.1
    assert _valid(poses, cov, commands, moving, seen, ranges, bearings).tolist() == [True, False, False, True]


def test_solve_chunks_writes_the_solved_samples_and_flags_the_failed_ones():
    """Samples 0, 2, 3, 5 to solve in chunks of 3 ([0, 2, 3], [5]); the solver (here: prior + 1, covariance x 2)
    fails on sample 3. Solved samples get its answer; sample 3 keeps its poses and covariance and gets
    ok = False; samples 1 and 4 (not to solve) are untouched."""
    b, n = 6, 2
    dr_poses = np.arange(b * n * 3, dtype=float).reshape(b, n, 3)
    dr_cov = np.broadcast_to(np.eye(3), (b, n, 3, 3)).copy()
    seen = np.ones((b, n, n), bool)
    ranges = bearings = np.zeros((b, n, n))
    calls = []

    def solve(cfg, p, c, s, r, br, ws):
        calls.append(len(p))
        return p + 1.0, 2.0 * c, np.array([k != 2 for k in range(len(p))]) if len(p) == 3 else np.ones(len(p), bool)

    poses, cov, ok = dr_poses.copy(), dr_cov.copy(), np.array([True, False, True, True, False, True])
    _solve_chunks(solve, CFG, np.array([0, 2, 3, 5]), 3, dr_poses, dr_cov, seen, ranges, bearings, poses, cov, ok, None)
    assert calls == [3, 1]
    assert ok.tolist() == [True, False, True, False, False, True]
    for k in range(b):
        solved = k in (0, 2, 5)
        np.testing.assert_array_equal(poses[k], dr_poses[k] + (1.0 if solved else 0.0))
        np.testing.assert_array_equal(cov[k], dr_cov[k] * (2.0 if solved else 1.0))


@pytest.mark.parametrize(
    "cov",
    [
        [[4.0, 0.0, 2.0], [0.0, 1.0, 0.0], [2.0, 0.0, 1.0]],  # x and heading perfectly correlated (singular)
        [[1.0, 0.0, 0.0], [0.0, 4.0, 2.0], [0.0, 2.0, 1.0]],  # y and heading perfectly correlated (singular)
        [[4.0, 2.5, 0.0], [2.5, 1.0, 0.0], [0.0, 0.0, -1.0]],  # two negative eigenvalues: det > 0, minor 2 < 0
    ],
)
def test_prior_information_floors_what_only_one_minor_reveals(cov):
    """Covariances whose first leading minor is positive but which are not clearly positive definite, each
    revealed by one minor only (the determinant for the singular ones, the second minor for the indefinite
    one, whose determinant is positive): W^T W is the floored inverse V diag(1 / max(lambda, 1e-12)) V^T of
    the eigen-decomposition, not the plain inverse."""
    cov = np.array(cov)
    lam, vec = np.linalg.eigh(cov)
    want = (vec / np.maximum(lam, 1e-12)) @ vec.T
    np.testing.assert_allclose(prior_information(cov[None])[0], want, rtol=1e-6, atol=1e-3)


@pytest.mark.parametrize("method", BUILTIN_LOCALIZERS)
def test_a_single_robot_is_dead_reckoning(method):
    """n = 1: nobody can observe the only robot, so it is not localized (ok False) and keeps its dead
    reckoning: 0.1 m along its heading 0."""
    out = localize_batch(make_localizer(method, CFG), CFG, np.zeros((2, 1, 3)), np.broadcast_to(np.eye(3) * 1e-4, (2, 1, 3, 3)),
                         np.array([[[0.0, 0.1]]] * 2), np.ones((2, 1), bool), np.zeros((2, 1, 1), bool),
                         np.zeros((2, 1, 1)), np.zeros((2, 1, 1)))
    assert out.ok.tolist() == [False, False]
    driven = driven_x(make_localizer(method, CFG), np.eye(3) * 1e-4, 0.1)
    np.testing.assert_allclose(out.poses[:, 0], [[driven, 0.0, 0.0]] * 2, atol=1e-15)


def test_an_ill_conditioned_constrained_update_is_done_densely():
    """Noise-free sensing (whitening 1e9) and a prior that disagrees with it by 0.1 mm: the Woodbury identity's 6x6
    system has a condition number ~1e28 and gave poses 3e7 m off; the batch then does the dense update of the
    single-swarm localizer, and both put every robot within 0.3 mm of the truth (the prior's disagreement); so do the
    poses alone (``covariances=False``)."""
    from runtime.models.motion import apply_motion
    from runtime.models.rng import Stream, robot_rngs
    from runtime.models.scenarios import grid_configuration
    from runtime.models.sensing import sense_swarm
    from runtime.models.state import Observations, StepCommands, SwarmEstimate

    cfg = ModelConfig(range_sigma_m=0.0, bearing_sigma_rad=0.0)
    rng = np.random.default_rng(40)
    n = 10
    poses = grid_configuration(n, 0.22, rng)
    ids = np.arange(n)
    moving = rng.random(n) < 0.5
    commands = np.column_stack([rng.uniform(-1, 1, n), rng.uniform(0.05, 0.15, n)]) * moving[:, None]
    after = np.where(moving[:, None], apply_motion(poses, commands), poses)
    obs = sense_swarm(after, ids, cfg, robot_rngs(0, ids, Stream.SENSING))
    prior = SwarmEstimate.isotropic(ids, poses + rng.normal(0, 1e-4, poses.shape), 0.01, 0.02)
    seen = np.zeros((n, n), bool)
    seen[obs.observer, obs.observed] = True
    ranges, bearings = np.zeros((n, n)), np.zeros((n, n))
    ranges[obs.observer, obs.observed], bearings[obs.observer, obs.observed] = obs.range_m, obs.bearing_rad
    arrays = prior.poses[None], prior.cov[None], commands[None], moving[None], seen[None], ranges[None], bearings[None]
    out = localize_batch(make_localizer("joint", cfg), cfg, *arrays)
    np.testing.assert_allclose(localize_batch(make_localizer("joint", cfg), cfg, *arrays, covariances=False).poses, out.poses, rtol=0, atol=1e-12)
    observations = Observations(*np.nonzero(seen), ranges[seen], bearings[seen])
    single = make_localizer("joint", cfg).localize(prior, StepCommands(ids, commands, moving), observations)
    assert out.ok[0]
    assert np.abs(out.poses[0, :, :2] - after[:, :2]).max() < 3e-4
    assert np.abs(single.poses[:, :2] - after[:, :2]).max() < 3e-4
    assert np.isfinite(out.cov).all()


def test_lm_returns_every_samples_state_at_its_solution(monkeypatch):
    """``drive`` returns the state of every sample at its solution, also of those that left the work set before the
    end (the joint solve reads it instead of evaluating the batch again): the same arrays, bit for bit, as a fresh
    evaluation at the returned points. Samples with 0-8x the sensing noise converge after different iteration counts."""
    rng = np.random.default_rng(21)
    b, n = 12, 5
    truth = np.column_stack([rng.uniform(0.0, 0.3, (n, 2)), rng.uniform(-np.pi, np.pi, n)])
    d = truth[None, :, :2] - truth[:, None, :2]
    scale = np.repeat([0.0, 1.0, 3.0, 8.0], 3)[:, None, None]
    ranges = np.hypot(d[..., 0], d[..., 1]) + scale * CFG.range_sigma_m * rng.normal(size=(b, n, n))
    bearings = np.arctan2(d[..., 1], d[..., 0]) - truth[:, None, 2] + scale * CFG.bearing_sigma_rad * rng.normal(size=(b, n, n))
    seen = np.broadcast_to(~np.eye(n, dtype=bool), (b, n, n))
    prior = truth + rng.normal(size=(b, n, 3)) * [0.01, 0.01, 0.03]
    cov = np.broadcast_to(np.diag([1e-4, 1e-4, 1e-3]), (b, n, 3, 3))
    problem = _JointProblem(seen, ranges, bearings, prior, prior_information(cov), CFG.range_sigma_m, CFG, _Workspace())
    subsets = []
    subset = _JointProblem.subset
    monkeypatch.setattr(_JointProblem, "subset", lambda self, index: subsets.append(len(index)) or subset(self, index))
    x, _, _, st = drive(problem, prior, *JOINT_TOL, xp=BatchOps)
    assert subsets  # some samples left the work set
    kept = {key: value.copy() for key, value in st.items()}
    fresh = problem.evaluate(x)
    assert kept.keys() == fresh.keys()
    for key, value in fresh.items():
        np.testing.assert_array_equal(kept[key], value, err_msg=key)
