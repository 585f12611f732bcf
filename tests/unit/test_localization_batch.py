"""Batched localization (coordinator.localization.batch) against the single-swarm localizers."""

from __future__ import annotations

import math
import resource
import sys

import numpy as np
import pytest

import coordinator.localization.batch as batch_module
import coordinator.localization.joint as joint_module
import coordinator.localization.topology as topology_module
from coordinator.localization import make_localizer
from coordinator.localization.allocator import retain_freed_memory
from coordinator.localization.batch import localize_batch, observable
from coordinator.localization.dead_reckoning import dead_reckon, dead_reckon_arrays, exact_moments
from coordinator.localization.graph import observable_subset, require_observable
from coordinator.localization.joint_normal import JointProblem
from coordinator.localization.partial import localize_observable
from coordinator.localization.range_bearing import sqrt_information
from coordinator.localization.registry import BUILTIN_LOCALIZERS
from coordinator.localization.sparse_lm import PoseLayout, dense as sparse_dense
from inchworm.noise import scaled
from runtime.errors import LocalizationError, SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.geometry import transform_poses, wrap_angle
from runtime.models.motion import apply_motion
from runtime.models.rng import Stream, robot_rngs
from runtime.models.scenarios import grid_configuration, random_step
from runtime.models.sensing import measure, sense_swarm
from runtime.models.state import Observations, StepCommands, SwarmEstimate

METHODS = BUILTIN_LOCALIZERS


def dense(obs: Observations, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(seen, ranges, bearings) (n, n) from observations of robots 0..n-1; NaN where unseen."""
    seen = np.zeros((n, n), bool)
    ranges, bearings = np.full((n, n), np.nan), np.full((n, n), np.nan)
    seen[obs.observer, obs.observed] = True
    ranges[obs.observer, obs.observed] = obs.range_m
    bearings[obs.observer, obs.observed] = obs.bearing_rad
    return seen, ranges, bearings


def rotate_cov(cov: np.ndarray, theta: float) -> np.ndarray:
    r = np.eye(3)
    r[:2, :2] = [[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]]
    return r @ cov @ r.T


class Batch:
    """Batch inputs, one sample per ``add``; ``single(k)`` rebuilds sample k for the single-swarm localizers."""

    def __init__(self) -> None:
        self.rows: list[tuple[np.ndarray, ...]] = []

    def add(self, prior: SwarmEstimate, step: StepCommands, seen, ranges, bearings) -> None:
        self.rows.append((prior.poses, prior.cov, step.commands, step.moving, seen, ranges, bearings))

    def arrays(self) -> list[np.ndarray]:
        return [np.stack(column) for column in zip(*self.rows, strict=True)]

    def single(self, k: int) -> tuple[SwarmEstimate, StepCommands, Observations]:
        poses, cov, commands, moving, seen, ranges, bearings = self.rows[k]
        ids = np.arange(len(poses))
        i, j = np.nonzero(seen)  # ordered by (observer, observed)
        obs = Observations(i, j, ranges[i, j], bearings[i, j])
        return SwarmEstimate(ids, poses, cov), StepCommands(ids, commands, moving), obs


def random_batch(n: int, size: int, cfg: ModelConfig, seed: int) -> Batch:
    """Random steps with dropout (different in every sample). Sample k % 4 == 1: a robot observes
    nobody (one-way observations); 2: an anchor's heading at the +-pi seam; 3: exact priors for
    the anchors (k % 8 == 3) or a robot nobody observes (k % 8 == 7, not localizable)."""
    batch = Batch()
    for k in range(size):
        rng = np.random.default_rng([seed, k])
        case = random_step(n, cfg, rng, spacing=0.22, seed=seed + k)
        prior = case.prior
        seen, ranges, bearings = dense(case.observations, n)
        step = case.step
        kind = k % 4
        if kind == 1:  # robot 2 observes nobody (others still observe it): one-way observations
            seen[2, :] = False
        elif kind == 2:  # rigid motion of the scene so that anchor 1's heading sits at the +-pi seam
            theta = (math.pi - 1e-6) - prior.poses[1, 2]
            moved = transform_poses(prior.poses, theta, np.array([1.0, -2.0]))
            prior = SwarmEstimate(prior.ids, moved, rotate_cov(prior.cov, theta))
            moving = step.moving.copy()
            moving[1] = False
            step = StepCommands(step.ids, step.commands, moving)
        elif kind == 3 and k % 8 == 3:  # exact priors (zero covariance) for two anchors
            cov = prior.cov.copy()
            cov[~step.moving] = 0.0
            prior = SwarmEstimate(prior.ids, prior.poses, cov)
        elif kind == 3:  # nobody observes robot 0: not localizable
            seen[:, 0] = False
        seen &= rng.random((n, n)) >= 0.1  # extra dropout, different in every sample
        batch.add(prior, step, seen, ranges, bearings)
    return batch


def assert_same_estimate(got_poses, got_cov, want: SwarmEstimate) -> None:
    """Poses to 1e-10 (m, rad), covariances to 1e-7 of each robot's 3x3 block (measured: below 1e-11 and 5e-9, the
    latter on exact priors, whose information 1e12 leaves the inverse at rounding)."""
    np.testing.assert_allclose(got_poses[:, :2], want.poses[:, :2], rtol=0, atol=1e-10)
    np.testing.assert_allclose(wrap_angle(got_poses[:, 2] - want.poses[:, 2]), 0.0, atol=1e-10)
    scale = np.abs(want.cov).max(axis=(1, 2), keepdims=True)  # relative to each robot's 3x3 block
    assert np.all(np.abs(got_cov - want.cov) <= 1e-7 * scale)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize(("n", "size"), [(6, 16), (25, 8)])
def test_batch_equals_single_swarm_localizer(method, n, size):
    cfg = ModelConfig(dropout_prob=0.15)
    batch = random_batch(n, size, cfg, seed=10 * n)
    out = localize_batch(make_localizer(method, cfg), cfg, *batch.arrays())
    assert out.poses.shape == (size, n, 3) and out.cov.shape == (size, n, 3, 3) and out.ok.shape == (size,)
    localized = 0
    for k in range(size):
        prior, step, obs = batch.single(k)
        if not observable_subset(prior.ids, *obs.indexed(prior.ids))[0].all():  # a run's rule, which the batch keeps
            assert not out.ok[k]  # not fully localized: the runtime's partial answer, as in the executor
            partial, excluded = localize_observable(make_localizer(method, cfg), prior, step, obs, cfg)
            assert_same_estimate(out.poses[k], out.cov[k], partial)
            dr = dead_reckon(prior, step, cfg, exact_moments(make_localizer(method, cfg)))
            kept_dr = np.isin(prior.ids, list(excluded))
            np.testing.assert_allclose(out.poses[k][kept_dr], dr.poses[kept_dr], rtol=0, atol=1e-12)
            continue
        want = make_localizer(method, cfg).localize(prior, step, obs)
        assert out.ok[k], f"sample {k} not localized"
        assert_same_estimate(out.poses[k], out.cov[k], want)
        localized += 1
    assert localized >= size - 3  # the batch mixes localizable and non-localizable samples
    assert not out.ok.all()


@pytest.mark.parametrize("method", METHODS)
def test_chunks_give_the_same_answer(method, monkeypatch):
    cfg = ModelConfig(dropout_prob=0.15)
    arrays = random_batch(6, 19, cfg, seed=3).arrays()
    whole = localize_batch(make_localizer(method, cfg), cfg, *arrays)
    monkeypatch.setattr(batch_module, "CHUNK_PAIRS", 1)  # chunks of MIN_CHUNK samples, the last one partial
    chunked = localize_batch(make_localizer(method, cfg), cfg, *arrays)
    np.testing.assert_array_equal(chunked.ok, whole.ok)
    np.testing.assert_allclose(chunked.poses, whole.poses, rtol=0, atol=1e-12)
    np.testing.assert_allclose(chunked.cov, whole.cov, rtol=1e-10, atol=0)


@pytest.mark.parametrize(("method", "constrain"), [("joint", True), ("joint", False), ("paper", True)])
def test_poses_alone_are_the_same_poses(method, constrain):
    """``covariances=False`` (the Monte Carlo's last step of a plan): the same flags and the same poses to rounding
    (the constrained update solves for them instead of inverting the Schur complement; measured <= 9e-16 m), with
    unobservable samples in the batch; the joint method leaves the covariances of what it solved NaN."""
    cfg = ModelConfig(dropout_prob=0.15)
    arrays = random_batch(8, 16, cfg, seed=8).arrays()
    localizer = make_localizer(method, cfg) if method == "paper" else make_localizer(method, cfg, constrain_gauge=constrain)
    full = localize_batch(localizer, cfg, *arrays)
    alone = localize_batch(localizer, cfg, *arrays, covariances=False)
    np.testing.assert_allclose(alone.poses, full.poses, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(alone.ok, full.ok)
    assert full.ok.sum() >= 8 and not full.ok.all()
    if method == "joint":
        assert np.isnan(alone.cov[full.ok]).all()
    else:
        np.testing.assert_array_equal(alone.cov, full.cov)


def test_joint_block_covariances_above_the_exact_limit(monkeypatch):
    """Above EXACT_COV_LIMIT robots both compute conditional covariances from the 3x3 information blocks."""
    monkeypatch.setattr(joint_module, "EXACT_COV_LIMIT", 4)
    monkeypatch.setattr(batch_module, "EXACT_COV_LIMIT", 4)
    cfg = ModelConfig()
    batch = random_batch(6, 4, cfg, seed=77)
    out = localize_batch(make_localizer("joint", cfg), cfg, *batch.arrays())
    for k in np.flatnonzero(out.ok):
        assert_same_estimate(out.poses[k], out.cov[k], make_localizer("joint", cfg).localize(*batch.single(k)))
    assert out.ok.sum() >= 2


def two_groups(cfg: ModelConfig) -> tuple[SwarmEstimate, StepCommands, tuple[np.ndarray, ...]]:
    """Six robots in two groups out of each other's sensing range."""
    ids = np.arange(6)
    poses = np.array([[0, 0, 0.1], [0.2, 0, 1.0], [0.1, 0.2, 2.0], [3, 3, -1.0], [3.2, 3, 0.3], [3.1, 3.2, 2.5]])
    obs = sense_swarm(poses, ids, cfg, robot_rngs(0, ids, Stream.SENSING))
    return SwarmEstimate.isotropic(ids, poses, 0.01, 0.01), StepCommands.stationary(ids), dense(obs, 6)


@pytest.mark.parametrize("method", METHODS)
def test_non_observable_samples_are_localized_like_the_runtime(method):
    """Largest observable group localized, the rest dead reckoning: the executor's partial localization."""
    cfg = ModelConfig()
    case = random_step(6, cfg, np.random.default_rng(3), spacing=0.2)
    seen, ranges, bearings = dense(case.observations, 6)
    blind = seen.copy()
    blind[:, 4] = blind[4, :] = False  # robot 4 observes nobody and nobody observes it
    split_prior, split_step, split_obs = two_groups(cfg)
    assert split_obs[0].any(axis=0).all()  # everyone is observed, but in two groups

    batch = Batch()
    batch.add(case.prior, case.step, seen, ranges, bearings)
    batch.add(case.prior, case.step, blind, ranges, bearings)
    batch.add(split_prior, split_step, *split_obs)
    batch.add(case.prior, case.step, seen, ranges, bearings)
    out = localize_batch(make_localizer(method, cfg), cfg, *batch.arrays())
    np.testing.assert_array_equal(out.ok, [True, False, False, True])
    for k, reason in ((1, "unobserved"), (2, "disconnected")):
        prior, step, obs = batch.single(k)
        with pytest.raises(LocalizationError, match=reason):
            make_localizer(method, cfg).localize(prior, step, obs)
        partial, excluded = localize_observable(make_localizer(method, cfg), prior, step, obs, cfg)
        assert set(excluded.values()) == {reason} and len(excluded) < 6
        assert_same_estimate(out.poses[k], out.cov[k], partial)
        dr = dead_reckon(prior, step, cfg, exact_moments(make_localizer(method, cfg)))
        left = np.isin(prior.ids, list(excluded))
        np.testing.assert_allclose(out.poses[k][left], dr.poses[left], rtol=0, atol=1e-12)
        assert np.abs(out.poses[k][~left] - dr.poses[~left]).max() > 0  # the others were localized
    alone = localize_batch(make_localizer(method, cfg), cfg, *[a[:1] for a in batch.arrays()])
    want = make_localizer(method, cfg).localize(case.prior, case.step, case.observations)
    for k in (0, 3):  # the localizable samples are unaffected by their neighbours in the batch
        np.testing.assert_array_equal(out.poses[k], out.poses[0])
        np.testing.assert_allclose(out.poses[k], alone.poses[0], rtol=0, atol=1e-12)
        assert_same_estimate(out.poses[k], out.cov[k], want)


@pytest.mark.parametrize("method", METHODS)
def test_noise_free_sensing_and_motion_recover_the_truth(method):
    cfg = ModelConfig(range_sigma_m=0.0, bearing_sigma_rad=0.0)
    batch, truths = Batch(), []
    for k in range(6):
        rng = np.random.default_rng(40 + k)
        n = 10
        poses = grid_configuration(n, 0.22, rng)
        poses[k % n, 2] = math.pi - 1e-4  # headings across the +-pi seam
        poses[(k + 1) % n, 2] = -math.pi + 1e-4
        ids = np.arange(n)
        moving = rng.random(n) < 0.5
        commands = np.column_stack([rng.uniform(-1, 1, n), rng.uniform(0.05, 0.15, n)]) * moving[:, None]
        prior, step = SwarmEstimate.isotropic(ids, poses, 0.01, 0.02), StepCommands(ids, commands, moving)
        after = dead_reckon(prior, step, cfg, exact_moments(make_localizer(method, cfg))).poses  # the motion the localizer expects
        obs = sense_swarm(after, ids, cfg, robot_rngs(k, ids, Stream.SENSING))
        batch.add(prior, step, *dense(obs, n))
        truths.append(after)
    out = localize_batch(make_localizer(method, cfg), cfg, *batch.arrays())
    assert out.ok.all()
    truth = np.stack(truths)
    np.testing.assert_allclose(out.poses[..., :2], truth[..., :2], rtol=0, atol=1e-9)
    np.testing.assert_allclose(wrap_angle(out.poses[..., 2] - truth[..., 2]), 0.0, atol=1e-9)


def test_values_of_unseen_pairs_are_ignored_and_bad_samples_are_flagged():
    cfg = ModelConfig()
    batch = random_batch(6, 3, cfg, seed=5)
    poses, cov, commands, moving, seen, ranges, bearings = batch.arrays()
    out = localize_batch(make_localizer("paper", cfg), cfg, poses, cov, commands, moving, seen, ranges, bearings)
    garbage = np.where(seen, ranges, 123.0), np.where(seen, bearings, -7.0)
    np.testing.assert_array_equal(localize_batch(make_localizer("paper", cfg), cfg, poses, cov, commands, moving, seen, *garbage).poses, out.poses)
    i, j = np.argwhere(seen[1])[0]
    ranges[1, i, j] = np.nan  # a seen pair without a value: the single-swarm input would be rejected
    bad = localize_batch(make_localizer("paper", cfg), cfg, poses, cov, commands, moving, seen, ranges, bearings)
    np.testing.assert_array_equal(bad.ok, [out.ok[0], False, out.ok[2]])
    np.testing.assert_array_equal(bad.poses[[0, 2]], out.poses[[0, 2]])


def test_observability_matches_the_single_swarm_rules():
    """The batch keeps to a run's rule (``observable_subset``: everyone observed, one group); a sample it
    finds observable also passes ``require_observable``, which accepts more (a robot fixed by what it saw)."""
    rng = np.random.default_rng(0)
    seen = rng.random((200, 7, 7)) < 0.22
    got = observable(seen & ~np.eye(7, dtype=bool))
    for k in range(200):
        i, j = np.nonzero(seen[k] & ~np.eye(7, dtype=bool))
        assert got[k] == observable_subset(np.arange(7), i, j)[0].all()
        if got[k]:
            require_observable(np.arange(7), i, j)
    assert 0 < got.sum() < 200


def test_bad_shapes_and_methods_are_rejected():
    cfg = ModelConfig()
    poses, cov, commands, moving, seen, ranges, bearings = random_batch(5, 2, cfg, seed=1).arrays()
    with pytest.raises(SwarmInputError, match="unknown localizer"):
        localize_batch(make_localizer("kalman", cfg), cfg, poses, cov, commands, moving, seen, ranges, bearings)
    with pytest.raises(SwarmInputError, match="seen must have shape"):
        localize_batch(make_localizer("paper", cfg), cfg, poses, cov, commands, moving, seen[:, :4], ranges, bearings)


# --------------------------------------------------------------------------------------------
# The batch's least-squares problems against the single-swarm normal equations, term by term


def lm_step(normal, gradient, mu: float, curvature=None) -> np.ndarray:
    """``sparse_lm.minimize``'s step: (A + C + mu D) dx = -g, D = diag(A) floored at 1e-12, C = the curvature
    floored at -0.9 D (only when given).

    Solved on the Jacobi-scaled system S M S (S^-1 dx) = -S g, S = diag(M)^-1/2: an exact prior puts 1e12 on
    some diagonal entries (condition ~1e9), and an unscaled LU solve then carries a relative error of ~1e-7 in
    the small components (cond x eps, LAPACK-build dependent), which is the reference's rounding, not the batch's.
    Scaled, the condition number is ~10 and the reference is exact to ~1e-15."""
    a = np.array(sparse_dense(normal), dtype=float)
    diag = np.maximum(np.diag(a), 1e-12)
    if curvature is not None:
        a += np.diag(np.maximum(curvature, -0.9 * diag))
    m = a + np.diag(mu * diag)
    scale = 1.0 / np.sqrt(np.abs(np.diag(m)))
    return scale * np.linalg.solve(m * scale[:, None] * scale[None, :], -gradient * scale)


def batch_problem(monkeypatch, method: str, cfg: ModelConfig, arrays):
    """The problem and start ``localize_batch`` hands its Levenberg-Marquardt (the first call)."""
    seen, real = [], batch_module.drive

    def spy(problem, x0, *args, **kw):
        seen.append((problem, np.array(x0)))
        return real(problem, x0, *args, **kw)

    monkeypatch.setattr(batch_module, "drive", spy)
    out = localize_batch(make_localizer(method, cfg), cfg, *arrays)
    assert out.ok.all()  # every sample in the one problem, in order
    return seen[0]


MUS = np.array([1e-8, 0.3, 2.0, 1e-3])  # per sample: damping that matters (and that does not)


@pytest.mark.parametrize("seed", [1, 6])
def test_topology_problem_is_the_single_swarm_one(monkeypatch, seed):
    """The batch's Eq. B3 problem equals ``estimate_topology``'s at the start and at a perturbed point: the cost
    0.5 |r|^2 and the damped step (J^T J + C + mu D) dx = -J^T r, with the clamped second-order heading term C
    where ``curved`` and without it elsewhere. Unknowns the single-swarm layout holds fixed (the reference
    robot's pose, the heading of robot 2 that observed nobody in sample 1) must not move."""
    cfg = ModelConfig(dropout_prob=0.15)
    batch = random_batch(6, 4, cfg, seed=seed)
    problem, x0 = batch_problem(monkeypatch, "paper", cfg, batch.arrays())
    closures, real = [], topology_module.levenberg_marquardt

    def spy(residuals, x_start, **kw):
        closures.append((residuals, kw["second_order"]))
        return real(residuals, x_start, **kw)

    monkeypatch.setattr(topology_module, "levenberg_marquardt", spy)
    rng = np.random.default_rng(seed)
    layouts = []
    perturbed = x0 + 0.03 * rng.normal(size=x0.shape)
    for k in range(4):
        prior, step, obs = batch.single(k)
        make_localizer("paper", cfg).localize(prior, step, obs)
        has_heading = np.bincount(obs.observer, minlength=6) > 0
        assert has_heading[2] == (k != 1)
        free = np.arange(6) != np.argmax(has_heading)
        layout = PoseLayout(free, free & has_heading)
        layouts.append(layout)
        perturbed[k][layout.cols < 0] = x0[k][layout.cols < 0]
    for x in (x0, perturbed):
        st = problem.evaluate(x, 0)
        for curved in (np.array([False, True, False, True]), np.array([True, False, True, False])):
            dx, predicted = problem.step(st, MUS, curved)
            for k, layout in enumerate(layouts):
                residuals, second_order = closures[k]
                vec = layout.pack(x[k])
                r, jac = residuals(vec)
                jac = sparse_dense(jac)
                assert st["cost"][k] == pytest.approx(0.5 * r @ r, rel=1e-12)
                curvature = second_order(vec, r) if curved[k] else None
                want = layout.unpack(lm_step(jac.T @ jac, jac.T @ r, MUS[k], curvature), np.zeros((6, 3)))
                np.testing.assert_allclose(dx[k], want, rtol=0, atol=1e-12 * np.abs(want).max())
                # the step's predicted decrease -g.dx / 2 (sparse_lm.minimize's ptol)
                assert predicted[k] == pytest.approx(-0.5 * (jac.T @ r) @ layout.pack(dx[k]), rel=1e-8)


def test_joint_problem_is_the_single_swarm_one(monkeypatch):
    """The batch's joint problem equals ``joint_normal.JointProblem``'s on the dead-reckoning prior at the start
    and at a perturbed point: the cost, the damped step (J^T J + mu D) dx = -J^T r (positions and headings),
    and the 3x3 blocks of (J^T J)^-1 (the covariances; above EXACT_COV_LIMIT those of each robot's own
    information block). Sample 3 has exact priors (zero covariance, floored information 1e12)."""
    cfg = ModelConfig(dropout_prob=0.15)
    batch = random_batch(6, 4, cfg, seed=8)
    arrays = batch.arrays()
    problem, x0 = batch_problem(monkeypatch, "joint", cfg, arrays)
    dr_poses, dr_cov = dead_reckon_arrays(*arrays[:4], cfg, exact=True)
    np.testing.assert_array_equal(x0, dr_poses)
    singles = []
    for k in range(4):
        _, _, obs = batch.single(k)
        singles.append(JointProblem(dr_poses[k], sqrt_information(dr_cov[k]), obs.observer, obs.observed,
                                    obs.range_m, obs.bearing_rad, cfg))
    perturbed = x0 + 0.03 * np.random.default_rng(2).normal(size=x0.shape)
    for x in (x0, perturbed):
        st = problem.evaluate(x, 0)
        dx, predicted = problem.step(st, MUS, np.array([False, True, False, True]))
        cov = batch_module._joint_covariances(*problem.normal(st))
        monkeypatch.setattr(batch_module, "EXACT_COV_LIMIT", 4)
        blocks = batch_module._joint_covariances(*problem.normal(st))
        monkeypatch.undo()
        for k, single in enumerate(singles):
            ne = single.evaluate(x[k].ravel())
            assert st["cost"][k] == pytest.approx(ne.cost, rel=1e-10)
            want = lm_step(ne.normal, ne.gradient, MUS[k]).reshape(6, 3)
            np.testing.assert_allclose(dx[k], want, rtol=0, atol=1e-12 * np.abs(want).max())
            assert predicted[k] == pytest.approx(-0.5 * ne.gradient @ want.ravel(), rel=1e-10)
            info = sparse_dense(ne.normal)
            inv = np.linalg.inv(info)
            for a in range(6):
                sl = slice(3 * a, 3 * a + 3)
                np.testing.assert_allclose(cov[k, a], inv[sl, sl], rtol=1e-7, atol=1e-9 * np.abs(inv[sl, sl]).max())
                np.testing.assert_allclose(blocks[k, a], np.linalg.inv(info[sl, sl]), rtol=1e-7)


def test_partial_localization_ignores_values_of_unseen_pairs():
    """Nobody observes robot 4, and every unseen pair holds finite garbage (123 m, -7 rad): the batch's partial
    localization of the joint method (its own solve with robot 4's observations removed) uses only the
    observations among the other robots, as the runtime's ``localize_observable`` does."""
    cfg = ModelConfig()
    case = random_step(6, cfg, np.random.default_rng(3), spacing=0.2)
    seen, ranges, bearings = dense(case.observations, 6)
    seen[:, 4] = False
    batch = Batch()
    batch.add(case.prior, case.step, seen, np.where(seen, ranges, 123.0), np.where(seen, bearings, -7.0))
    out = localize_batch(make_localizer("joint", cfg), cfg, *batch.arrays())
    assert out.ok.tolist() == [False]
    partial, excluded = localize_observable(make_localizer("joint", cfg), *batch.single(0), cfg)
    assert excluded == {4: "unobserved"}
    assert_same_estimate(out.poses[0], out.cov[0], partial)


@pytest.mark.parametrize("method", METHODS)
def test_the_two_evaluation_slots_coexist(monkeypatch, method):
    """``evaluate(x, slot)`` keeps one state per slot (0 or 1): the Levenberg-Marquardt holds the current point's
    state in one while it tries a step in the other. A state evaluated in slot 0 is unchanged by an evaluation
    of another point in slot 1, and equals a fresh evaluation at its point."""
    cfg = ModelConfig(dropout_prob=0.15)
    batch = random_batch(6, 4, cfg, seed=1 if method == "paper" else 8)
    problem, x0 = batch_problem(monkeypatch, method, cfg, batch.arrays())
    perturbed = x0 + 0.03 * np.random.default_rng(0).normal(size=x0.shape)
    first = problem.evaluate(x0, 0)
    kept = {key: np.array(value) for key, value in first.items()}
    other = problem.evaluate(perturbed, 1)
    assert np.all(other["cost"] != kept["cost"])
    for key, value in first.items():
        np.testing.assert_array_equal(value, kept[key])
    again = problem.evaluate(x0, 1)
    for key, value in again.items():
        np.testing.assert_array_equal(value, kept[key])


def test_batched_joint_covariance_is_the_gauge_constrained_one():
    """The Monte Carlo sees the joint localizer's observability constraint (``gauge``), exactly: on rough input the
    batch's poses and covariances equal ``JointLocalizer``'s (``constrain_gauge`` on, the default), and differ from
    the unconstrained localizer's by far more than the tolerance. Rough input: correlated prior covariances (x-y,
    x-heading and y-heading correlations up to 0.9, anisotropic), prior headings within 1e-6 rad of +-pi on both
    sides, dropout, and samples where nobody observes one robot (the partial update of the others, whose gauge is
    theirs but whose covariance moves with the whole swarm's)."""
    cfg = ModelConfig(dropout_prob=0.2)
    n, size = 8, 12
    batch = Batch()
    for k in range(size):
        rng = np.random.default_rng([91, k])
        case = random_step(n, cfg, rng, spacing=0.22, seed=k)
        poses = case.prior.poses.copy()
        poses[k % n, 2] = math.pi - 1e-6 * rng.random()
        poses[(k + 3) % n, 2] = -math.pi + 1e-6 * rng.random()
        corr = rng.uniform(-0.9, 0.9, (n, 3))
        sigma = rng.uniform(0.005, 0.05, (n, 3)) * [1.0, 1.0, 2.0]  # m, m, rad
        cov = np.empty((n, 3, 3))
        for a in range(n):
            c = np.eye(3)
            c[0, 1] = c[1, 0] = corr[a, 0]
            c[0, 2] = c[2, 0] = corr[a, 1]
            c[1, 2] = c[2, 1] = corr[a, 2]
            lam, vec = np.linalg.eigh(c)
            c = (vec * np.maximum(lam, 0.05)) @ vec.T  # nearest valid correlation, kept strongly correlated
            cov[a] = c * np.outer(sigma[a], sigma[a])
        seen, ranges, bearings = dense(case.observations, n)
        if k % 4 == 3:
            seen[:, (k + 1) % n] = False  # nobody observes this robot: the others are localized without it
        batch.add(SwarmEstimate(case.prior.ids, poses, cov), case.step, seen, ranges, bearings)
    out = localize_batch(make_localizer("joint", cfg), cfg, *batch.arrays())
    plain = localize_batch(make_localizer("joint", cfg, constrain_gauge=False), cfg, *batch.arrays())
    assert (~out.ok).sum() >= 3 and out.ok.sum() >= 6
    moved = []
    for k in range(size):
        prior, step, obs = batch.single(k)
        want, excluded = localize_observable(make_localizer("joint", cfg), prior, step, obs, cfg)
        assert bool(excluded) == (not out.ok[k])
        np.testing.assert_allclose(out.poses[k, :, :2], want.poses[:, :2], rtol=0, atol=1e-10)
        np.testing.assert_allclose(wrap_angle(out.poses[k, :, 2] - want.poses[:, 2]), 0.0, atol=1e-10)
        scale = np.abs(want.cov).max(axis=(1, 2), keepdims=True)
        assert np.all(np.abs(out.cov[k] - want.cov) <= 1e-9 * scale)
        moved.append(np.max(np.abs(plain.cov[k] - want.cov) / scale))
    assert max(moved) > 1e-4  # the constraint matters at this tolerance: leaving it out would fail above


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator")
def test_a_repeated_batch_takes_no_page_faults():
    """The batch keeps freed memory for reuse (``allocator.retain_freed_memory``): localizing the same 128 swarms of
    10 robots again takes (almost) no page faults; with glibc's default thresholds it took ~2,400."""
    if not retain_freed_memory():
        pytest.skip("not glibc")
    cfg, n, b = ModelConfig(), 10, 128
    rng = np.random.default_rng(0)
    poses = grid_configuration(n, 0.2, rng)
    rho, phi = measure(poses[:, None, :], poses[None, :, :2])
    seen = np.broadcast_to((rho < cfg.sensing_range_m) & ~np.eye(n, dtype=bool), (b, n, n))
    args = (make_localizer("joint", cfg), cfg, poses + rng.normal(0.0, 0.01, (b, n, 3)), np.broadcast_to(np.diag([1e-4, 1e-4, 1e-3]), (b, n, 3, 3)),
            np.zeros((b, n, 2)), np.zeros((b, n), bool), seen, rho + rng.normal(0.0, 0.01, (b, n, n)), np.broadcast_to(phi, (b, n, n)))
    first = localize_batch(*args)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    again = localize_batch(*args)
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
    assert first.ok.all() and np.array_equal(first.poses, again.poses) and np.array_equal(first.cov, again.cov)
    assert faults < 200, faults


def test_a_wrong_local_minimum_is_solved_again_from_the_observations(monkeypatch):
    """A mover whose executed turn was 62 deg off (a 3.7-sigma error at the calibrated turn noise, 16.7 deg) with precise
    sensing (x0.25): started at the dead reckoning, Levenberg-Marquardt stops in a wrong minimum 19 cm from the truth
    (its cost is thousands for 2 m residuals). The implausible cost sends the solve to the observations' configuration
    (``joint.rescue_start``), single-swarm and batched alike, and both find the truth."""
    cfg = scaled(ModelConfig(), 5.58, 0.25)
    rng = np.random.default_rng(293)
    n = 6
    mean = np.column_stack([0.3 * (np.arange(n) % 3), 0.3 * (np.arange(n) // 3), rng.uniform(-math.pi, math.pi, n)])
    moving = np.arange(n) == 4
    cmd = np.zeros((n, 2))
    cmd[4] = [rng.uniform(-2, 2), 0.3]
    mean[4, :2] -= 0.3 * np.array([math.cos(mean[4, 2] + cmd[4, 0]), math.sin(mean[4, 2] + cmd[4, 0])])  # ends near its grid place
    prior = SwarmEstimate(np.arange(n), mean, np.broadcast_to(np.diag([1e-5, 1e-5, 1e-4]), (n, 3, 3)).copy())
    step = StepCommands(prior.ids, cmd, moving)
    truth = np.where(moving[:, None], apply_motion(mean, cmd, math.radians(61.8), 0.22), mean)
    obs = sense_swarm(truth, prior.ids, cfg, robot_rngs(293, prior.ids, Stream.SENSING))
    batch = Batch()
    batch.add(prior, step, *dense(obs, n))
    est = make_localizer("joint", cfg).localize(prior, step, obs)
    out = localize_batch(make_localizer("joint", cfg), cfg, *batch.arrays())
    assert np.abs(est.poses[:, :2] - truth[:, :2]).max() < 0.005
    assert out.ok[0]
    assert_same_estimate(out.poses[0], out.cov[0], est)
    monkeypatch.setattr(joint_module, "RESCUE_Z", 1e9)  # never implausible: the first minimum is kept
    wrong = make_localizer("joint", cfg).localize(prior, step, obs)
    assert np.abs(wrong.poses[4, :2] - truth[4, :2]).max() > 0.1


def test_ill_conditioned_matrices_are_those_np_linalg_cond_finds():
    """The Woodbury system's guard screens by the Frobenius bound and takes the SVD only where it does not decide: the same
    indices as ``np.linalg.cond`` on a rough stack (correlated, scaled across 1e-8..1e8, near-singular, singular)."""
    rng = np.random.default_rng(5)
    a = rng.normal(size=(40, 6, 6))
    a = a @ a.swapaxes(1, 2) + 1e-3 * np.eye(6)  # correlated
    a *= 10.0 ** rng.uniform(-8, 8, size=(40, 1, 1))
    u, _, vt = np.linalg.svd(rng.normal(size=(6, 6, 6)))
    for k, cond in enumerate((1e3, 3e10, 6e10, 9e10, 1.5e11, 1e14)):  # around the limit (1e11) and its half
        a[k] = (u[k] * np.geomspace(1.0, 1.0 / cond, 6)) @ vt[k]
    a[6] = 0.0  # singular
    a[7, 2] = a[7, 1]  # singular
    expected = np.flatnonzero(~(np.linalg.cond(a) <= batch_module.WOODBURY_COND_LIMIT))
    np.testing.assert_array_equal(batch_module._ill_conditioned(a), expected)
    assert {4, 5, 6, 7} <= set(expected.tolist()) and not {0, 1, 2, 3} & set(expected.tolist())
