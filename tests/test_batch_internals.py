"""Known answers for the batched localizer's input checks and linear-algebra helpers
(coordinator/localization/batch.py); its results against the single-swarm localizers are in
tests/test_localization_batch.py.

Each case is constructed so the answer is known without the code: which sample holds an invalid
value, the solution of a diagonal system, the inverse of a covariance.
"""

from __future__ import annotations

import numpy as np
import pytest

from coordinator.localization.batch import (
    _diagonal,
    _inv_stack,
    _prior_information,
    _solve_stack,
    _Workspace,
    localize_batch,
    observable,
)
from coordinator.localization.range_bearing import sqrt_information
from runtime.config import ModelConfig
from runtime.errors import SwarmInputError

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


@pytest.mark.parametrize("method", ["paper", "joint"])
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
        out = localize_batch(method, CFG, poses, cov, commands, moving, seen, ranges, bearings)
    assert out.ok.tolist() == [True, False, False, False, False, False, False, False, True, True]
    for k in (5, 6, 7):  # invalid observations: dead reckoning, robot 0 driven 0.1 m along x
        np.testing.assert_allclose(out.poses[k, 0], [0.1, 0.0, 0.0], atol=1e-12)
        np.testing.assert_allclose(out.poses[k, 1:], poses[k, 1:], atol=0)
    np.testing.assert_array_equal(out.poses[8], out.poses[0])


def test_no_robots_gives_empty_estimates():
    """n = 0: nothing to localize; every sample is ok and the arrays have shape (B, 0, ...)."""
    out = localize_batch("joint", CFG, np.zeros((2, 0, 3)), np.zeros((2, 0, 3, 3)), np.zeros((2, 0, 2)),
                         np.zeros((2, 0), bool), np.zeros((2, 0, 0), bool), np.zeros((2, 0, 0)), np.zeros((2, 0, 0)))
    assert out.ok.tolist() == [True, True]
    assert out.poses.shape == (2, 0, 3) and out.cov.shape == (2, 0, 3, 3)


def test_shapes_are_checked_with_their_names():
    """Every argument's shape is checked against (B, n, ...) and named in the message."""
    arrays = triangle_batch(2)
    names = ["prior_poses", "prior_cov", "commands", "moving", "seen", "ranges", "bearings"]
    for k, name in enumerate(names):
        bad = list(arrays)
        bad[k] = arrays[k][:, :2] if k else arrays[k][..., :2]
        with pytest.raises(SwarmInputError, match=f"{name} must have shape"):
            localize_batch("paper", CFG, *bad)
    with pytest.raises(SwarmInputError, match=r"prior_poses must have shape \(B, n, 3\), got \(3, 3\)"):
        localize_batch("paper", CFG, arrays[0][0], *arrays[1:])


def test_the_diagonal_of_seen_is_ignored():
    """A robot 'observing itself' (seen[b, i, i] with any value) changes nothing."""
    arrays = triangle_batch(1)
    base = localize_batch("joint", CFG, *arrays)
    seen, ranges = arrays[4].copy(), arrays[5].copy()
    seen[0, 1, 1], ranges[0, 1, 1] = True, 5.0
    out = localize_batch("joint", CFG, *arrays[:4], seen, ranges, arrays[6])
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
    """diag(2, 4) x = (2, 4) gives x = (1, 1); a zero matrix has no solution: NaN, the others unaffected."""
    a = np.stack([np.diag([2.0, 4.0]), np.zeros((2, 2)), np.diag([1.0, 0.5])])
    rhs = np.array([[2.0, 4.0], [1.0, 1.0], [3.0, 1.0]])
    out = _solve_stack(a, rhs)
    np.testing.assert_allclose(out[[0, 2]], [[1, 1], [3, 2]])
    assert np.isnan(out[1]).all()
    np.testing.assert_allclose(_solve_stack(a[[0, 2]], rhs[[0, 2]]), [[1, 1], [3, 2]])


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
    info = _prior_information(cov)
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
    np.testing.assert_allclose(_prior_information(np.diag(diagonal)[None])[0], want, rtol=1e-9)


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
