"""Known answers for the localization (Eq. 14-23, B1-B6) and the joint formulation's residuals.

coordinator/localization/{dead_reckoning, topology, superimpose, paper, range_bearing}.py.
Every number is derived by hand in the test's docstring; uncertainties are asymmetric
(delta_p != delta_u, different per robot) so a swapped weight or a wrong divisor shows.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from coordinator.localization.dead_reckoning import dead_reckon, dead_reckon_arrays
from coordinator.localization.paper import PaperLocalizer, fuse
from coordinator.localization.range_bearing import (
    COV_FLOOR,
    observation_terms,
    prior_terms,
    sensor_sigmas,
    sqrt_information,
    stack_terms,
)
from coordinator.localization.sparse_lm import PoseLayout
from coordinator.localization.superimpose import fusion_weights, superimpose, weighted_procrustes
from coordinator.localization.topology import (
    cluster_delta_p,
    estimate_topology,
    heading_sigmas,
    reference_robot,
    to_reference_frame,
)
from coordinator.localization.topology_terms import observation_offsets
from runtime.errors import LocalizationError
from runtime.models.config import ModelConfig
from runtime.models.state import Observations, StepCommands, SwarmEstimate

HALF_PI = math.pi / 2
SENSING = ModelConfig(range_sigma_m=0.01, bearing_sigma_rad=0.02)


def _exact_observations(poses: np.ndarray, pairs: list[tuple[int, int]]) -> tuple[np.ndarray, ...]:
    """Noise-free (observer, observed, rho, phi) (Eq. 20) of the given pairs."""
    i = np.array([a for a, _ in pairs])
    j = np.array([b for _, b in pairs])
    d = poses[j, :2] - poses[i, :2]
    rho = np.hypot(d[:, 0], d[:, 1])
    phi = np.arctan2(d[:, 1], d[:, 0]) - poses[i, 2]
    return i, j, rho, phi


# -- Eq. 17-19: dead reckoning ---------------------------------------------------------


def test_eq17_to_19_dead_reckoning_moves_movers_and_keeps_anchors():
    """Robot 0 at (1, 2) facing +y (pi/2) turns -pi/2 and drives 0.5: (1.5, 2, 0) (Eq. 17, 19).

    Robot 1 at (0, 0, 0) turns +pi/2 and drives 2: (0, 2, pi/2) (a sign error in the turn
    gives (0, -2)). Robot 2 is an anchor (Eq. 18): its command (0.3, 1.0) is ignored, pose
    and covariance unchanged.
    """
    prior = SwarmEstimate(
        np.array([4, 5, 6]),
        np.array([[1.0, 2.0, HALF_PI], [0.0, 0.0, 0.0], [3.0, 3.0, 1.0]]),
        np.stack([np.diag([0.01, 0.02, 0.03]), np.diag([0.04, 0.05, 0.06]), np.diag([0.07, 0.08, 0.09])]),
    )
    step = StepCommands(np.array([4, 5, 6]), np.array([[-HALF_PI, 0.5], [HALF_PI, 2.0], [0.3, 1.0]]), np.array([True, True, False]))
    out = dead_reckon(prior, step, ModelConfig())
    np.testing.assert_allclose(out.poses, [[1.5, 2.0, 0.0], [0.0, 2.0, HALF_PI], [3.0, 3.0, 1.0]], atol=1e-12)
    np.testing.assert_array_equal(out.cov[2], prior.cov[2])
    assert out.ids.tolist() == [4, 5, 6]


def test_dead_reckoning_covariance_first_order_known_case():
    """Heading 0, exact prior, command (turn 0, drive d = 2): Fu = [[0, d], [d, 0], [1, 0]] (columns: turn, drive frac).

    Q = diag(s_t^2, s_d^2) with s_t = 0.1 rad, s_d = 0.05: P' = Fu Q Fu^T =
    [[d^2 s_d^2, 0, 0], [0, d^2 s_t^2, d s_t^2], [0, d s_t^2, s_t^2]] = [[0.01, 0, 0], [0, 0.04, 0.02], [0, 0.02, 0.01]].
    Along the drive the error is the drive noise (x), across it the turn noise times d (y).
    With a prior heading variance 0.0025 (prior x, y exact): Fx adds [[0,0,0],[0, d^2 0.0025, d 0.0025],[0, ., 0.0025]].
    """
    cfg = ModelConfig(turn_sigma_rad=0.1, drive_sigma_frac=0.05)
    poses = np.zeros((2, 3))
    cov = np.zeros((2, 3, 3))
    cov[1, 2, 2] = 0.0025
    commands = np.array([[0.0, 2.0], [0.0, 2.0]])
    out, out_cov = dead_reckon_arrays(poses, cov, commands, np.array([True, True]), cfg)
    np.testing.assert_allclose(out, [[2.0, 0.0, 0.0], [2.0, 0.0, 0.0]], atol=1e-15)
    expected = np.array([[0.01, 0, 0], [0, 0.04, 0.02], [0, 0.02, 0.01]])
    np.testing.assert_allclose(out_cov[0], expected, atol=1e-15)
    np.testing.assert_allclose(out_cov[1], expected + [[0, 0, 0], [0, 0.01, 0.005], [0, 0.005, 0.0025]], atol=1e-15)


# -- Eq. B1, B6 and the topology (Eq. 14, B2-B5) ---------------------------------------------


def test_eqB1_cartesian_offsets():
    """z = (rho cos phi, rho sin phi) (Eq. B1): (2, pi/6) -> (sqrt(3), 1); (1, -pi/2) -> (0, -1); (0.5, pi) -> (-0.5, 0)."""
    z = observation_offsets(np.array([2.0, 1.0, 0.5]), np.array([math.pi / 6, -HALF_PI, math.pi]))
    np.testing.assert_allclose(z, [[math.sqrt(3), 1.0], [0.0, -1.0], [-0.5, 0.0]], atol=1e-12)


def test_eqB6_cluster_spread_uses_sample_standard_deviations():
    """Cluster of 3 points (0,0), (0.3,0), (0,0.3): centroid (0.1, 0.1).

    Sample variances (ddof = 1): x: (0.01 + 0.04 + 0.01)/2 = 0.03, y: 0.03; delta_p =
    sqrt(0.03 + 0.03) = sqrt(0.06) = 0.2449 (Eq. B6). Population variances would give 0.2,
    one axis only sqrt(0.03) = 0.173. The floor 0.5 sqrt(s_r^2 + (rho s_b)^2) at rho = 1 is
    0.5 sqrt(1e-4 + 4e-4) = 0.0112, far below.
    A cluster of one point gets exactly that single-observation spread, sqrt(5e-4) = 0.02236;
    a cluster of two identical points (spread 0) the half floor, 0.01118.
    """
    count = np.array([3.0, 1.0, 2.0])
    centroid = np.array([[0.1, 0.1], [5.0, 5.0], [1.0, 2.0]])
    sq = np.array([[0.09, 0.09], [25.0, 25.0], [2.0, 8.0]])
    mean_range = np.array([1.0, 1.0, 1.0])
    got = cluster_delta_p(count, centroid, sq, mean_range, SENSING)
    single = math.sqrt(0.01**2 + 0.02**2)
    np.testing.assert_allclose(got, [math.sqrt(0.06), single, 0.5 * single], rtol=1e-12)


def test_topology_of_three_robots_in_the_reference_robots_frame():
    """Eq. 14, B2-B5 with exact observations: the topology is the true configuration seen from robot 0.

    True poses r0 (1, 1, pi/2), r1 (1, 3, 0), r2 (-1, 1, pi); every robot sees every other.
    In r0's frame (rotate the offsets by -pi/2: (x, y) -> (y, -x)): r0 (0, 0, 0);
    r1 offset (0, 2) -> (2, 0), heading 0 - pi/2 = -pi/2; r2 offset (-2, 0) -> (0, 2), heading pi/2.
    Exact data: every cluster has zero spread, so delta_p is the floor 0.5 sqrt(s_r^2 + (rho_mean s_b)^2):
    r0 is seen at ranges 2 and 2 -> 0.5 sqrt(1e-4 + 0.04^2 ... ) with rho_mean 2: 0.5 sqrt(1e-4 + 1.6e-3);
    r1 at 2 and 2 sqrt(2): rho_mean 1 + sqrt(2); r2 at 2 and 2 sqrt(2): the same.
    Each robot made 2 observations: heading sigma s_b / sqrt(2).
    """
    poses = np.array([[1.0, 1.0, HALF_PI], [1.0, 3.0, 0.0], [-1.0, 1.0, math.pi]])
    pairs = [(a, b) for a in range(3) for b in range(3) if a != b]
    i, j, rho, phi = _exact_observations(poses, pairs)
    topo = estimate_topology(3, i, j, rho, phi, SENSING)
    assert topo.reference == 0
    np.testing.assert_allclose(topo.positions, [[0, 0], [2, 0], [0, 2]], atol=1e-7)
    np.testing.assert_allclose(topo.solved_positions, [[0, 0], [2, 0], [0, 2]], atol=1e-7)
    np.testing.assert_allclose(topo.headings, [0.0, -HALF_PI, HALF_PI], atol=1e-7)
    floor = [0.5 * math.hypot(0.01, r * 0.02) for r in (2.0, 1 + math.sqrt(2), 1 + math.sqrt(2))]
    np.testing.assert_allclose(topo.delta_p, floor, rtol=1e-6)
    np.testing.assert_allclose(topo.heading_sigma, [0.02 / math.sqrt(2)] * 3, rtol=1e-12)


def test_topology_clusters_are_centroids_of_inconsistent_observations():
    """Two robots that disagree: r0 sees r1 at 1.0 m straight ahead, r1 sees r0 at 1.2 m straight behind.

    Gauge r0 = (0, 0, 0). Q (Eq. B3) = |(1,0) - x1|^2 + |x1 + R(t1)(-1.2, 0)|^2; the second term
    is the distance of x1 from the circle of radius 1.2, so the minimiser is x1 = (1.1, 0), t1 = 0
    (Q = 0.01 + 0.01): the solved positions (Fig. B2 gray) are (0,0), (1.1,0).
    Clusters (Eq. B4): r1's only point is r0's observation, (1, 0); r0's only point is
    x1 + (-1.2, 0) = (-0.1, 0): the topology (Fig. B2 yellow) is (-0.1, 0), (1, 0).
    """
    topo = estimate_topology(2, np.array([0, 1]), np.array([1, 0]), np.array([1.0, 1.2]), np.array([0.0, math.pi]), SENSING)
    np.testing.assert_allclose(topo.solved_positions, [[0.0, 0.0], [1.1, 0.0]], atol=1e-7)
    np.testing.assert_allclose(topo.positions, [[-0.1, 0.0], [1.0, 0.0]], atol=1e-7)
    np.testing.assert_allclose(topo.headings, [0.0, 0.0], atol=1e-7)
    np.testing.assert_allclose(topo.delta_p, [math.hypot(0.01, 1.2 * 0.02), math.hypot(0.01, 1.0 * 0.02)], rtol=1e-9)


def test_robot_that_observes_nobody_has_no_heading_and_the_gauge_is_the_first_observer():
    """Robot 0 observes nobody: the reference is robot 1; robot 0's heading is NaN, its heading sigma inf.

    r1 (0,0,0) sees r0 at (0, 1) (rho 1, phi pi/2) and r2 at (1, 0); r2 (1, 0, pi) sees r1 at 1 m ahead.
    """
    i, j = np.array([1, 1, 2]), np.array([0, 2, 1])
    rho, phi = np.array([1.0, 1.0, 1.0]), np.array([HALF_PI, 0.0, 0.0])
    topo = estimate_topology(3, i, j, rho, phi, SENSING)
    assert topo.reference == 1
    np.testing.assert_allclose(topo.positions, [[0, 1], [0, 0], [1, 0]], atol=1e-7)
    assert math.isnan(topo.headings[0]) and topo.headings[1] == 0.0
    assert abs(abs(topo.headings[2]) - math.pi) < 1e-7
    np.testing.assert_allclose(topo.heading_sigma, [np.inf, 0.02 / math.sqrt(2), 0.02])
    assert reference_robot(np.array([[0, 0, 3], [2, 0, 1]])).tolist() == [2, 0]
    np.testing.assert_allclose(heading_sigmas(np.array([0, 4]), SENSING), [np.inf, 0.01])


def test_to_reference_frame_known_pose():
    """Pose (3, 1, 0.5) seen from (1, 1, pi/2): offset (2, 0) rotated by -pi/2 -> (0, -2); heading 0.5 - pi/2."""
    out = to_reference_frame(np.array([[3.0, 1.0, 0.5]]), np.array([1.0, 1.0, HALF_PI]))
    np.testing.assert_allclose(out, [[0.0, -2.0, 0.5 - HALF_PI]], atol=1e-12)


# -- Eq. 21-22: superimposition ---------------------------------------------------------


def test_eq22_weights():
    """w = 1 / (delta_p + delta_u): (0.1 + 0.3) -> 2.5, (0.02 + 0.08) -> 10; an exact pair is floored at 1/1e-9."""
    w = fusion_weights(np.array([0.1, 0.02, 0.0]), np.array([0.3, 0.08, 0.0]))
    np.testing.assert_allclose(w, [2.5, 10.0, 1e9], rtol=1e-12)


def test_eq21_weighted_translation_known_answer():
    """p = (-1,0), (1,0), (0,0); q = p except the middle point moved by (0.6, 0); weights 1, 1, 2.

    Normalised weights 1/4, 1/4, 1/2: p_c = (0, 0), q_c = (0.3, 0). Centred Q = (-1.3,0), (0.7,0), (0.3,0):
    every cross product is 0 and the dot product 0.25 (1.3 + 0.7) > 0, so theta = 0 and t = (0.3, 0).
    Equal weights would give t = (0.2, 0), inverted weights (1, 1, 1/2) t = (0.12, 0).
    """
    p = np.array([[-1.0, 0.0], [1.0, 0.0], [0.0, 0.0]])
    q = p + [[0.0, 0.0], [0.0, 0.0], [0.6, 0.0]]
    theta, t = superimpose(p, q, np.array([1.0, 1.0, 2.0]))
    assert theta == pytest.approx(0.0, abs=1e-15)
    np.testing.assert_allclose(t, [0.3, 0.0], atol=1e-15)
    _, _, spread = weighted_procrustes(p, q, np.array([1.0, 1.0, 2.0]))
    assert spread == pytest.approx(0.5, abs=1e-15)  # 1/4 + 1/4 + 0 (m^2)


def test_eq21_rotation_maps_topology_onto_configuration():
    """q = R(0.7) p + (1, -2) exactly, unequal weights: theta = +0.7 (p onto q, not q onto p) and t = (1, -2)."""
    p = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 1.0], [-1.0, -1.0]])
    c, s = math.cos(0.7), math.sin(0.7)
    q = p @ np.array([[c, s], [-s, c]]) + [1.0, -2.0]
    theta, t = superimpose(p, q, np.array([1.0, 5.0, 0.5, 2.0]))
    assert theta == pytest.approx(0.7, abs=1e-12)
    np.testing.assert_allclose(t, [1.0, -2.0], atol=1e-12)


def test_eq21_rotation_with_unequal_weights_known_answer():
    """p = (1,0), (-1,0); q = (1,0), (0,1) with weights w, w (then 3w, w): the angle between the centred pairs.

    Equal weights: p_c = 0, q_c = (0.5, 0.5); P = (1,0), (-1,0); Q = (0.5,-0.5), (-0.5,0.5);
    cross = 1/2 (1 (-0.5) + (-1)(0.5)) = -0.5, dot = 1/2 (0.5 + 0.5) = 0.5: theta = atan2(-0.5, 0.5) = -pi/4.
    Weights 3/4, 1/4: p_c = (0.5, 0), q_c = (0.75, 0.25); P = (0.5,0), (-1.5,0); Q = (0.25,-0.25), (-0.75,0.75):
    cross = 3/4 (0.5 (-0.25)) + 1/4 (-1.5 (0.75)) = -0.375, dot = 3/4 (0.125) + 1/4 (1.125) = 0.375: again -pi/4
    (both pairs span the same angle); t = q_c - R p_c = (0.75, 0.25) - (0.3536, -0.3536) = (0.3964, 0.6036).
    """
    p = np.array([[1.0, 0.0], [-1.0, 0.0]])
    q = np.array([[1.0, 0.0], [0.0, 1.0]])
    theta, t = superimpose(p, q, np.array([1.0, 1.0]))
    assert theta == pytest.approx(-math.pi / 4, abs=1e-12)
    np.testing.assert_allclose(t, [0.5, 0.5], atol=1e-12)
    theta, t = superimpose(p, q, np.array([3.0, 1.0]))
    assert theta == pytest.approx(-math.pi / 4, abs=1e-12)
    h = 0.5 / math.sqrt(2)
    np.testing.assert_allclose(t, [0.75 - h, 0.25 + h], atol=1e-12)


@pytest.mark.parametrize("w", [[1.0, 0.0, 1.0], [1.0, -1.0, 1.0], [1.0, np.inf, 1.0], [1.0, np.nan, 1.0]])
def test_eq21_bad_weights_are_refused(w):
    p = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    with pytest.raises(LocalizationError, match=r"^degenerate: robots \[\] \(superimposition weights must be finite and > 0\)$") as info:
        superimpose(p, p, np.array(w))
    assert info.value.reason == "degenerate"


def test_eq21_coincident_topology_is_refused():
    p = np.zeros((3, 2))
    with pytest.raises(LocalizationError, match="all topology points coincide") as info:
        superimpose(p, p + 1.0, np.ones(3))
    assert info.value.reason == "degenerate"


# -- Eq. 15, 23: the fused estimate -------------------------------------------------------


def _fuse_case():
    """Two robots; the topology frame at theta = pi/2, t = (1, 2) in the global frame."""
    topo_positions = np.array([[1.0, 0.0], [0.0, 2.0]])
    topo_headings = np.array([0.4, np.nan])
    delta_p = np.array([0.1, 0.2])
    heading_sigma = np.array([0.1, np.inf])
    dr_poses = np.array([[3.0, 3.0, HALF_PI], [0.0, 1.0, 0.3]])
    dr_cov = np.stack([np.diag([0.045, 0.045, 0.04]), np.diag([0.005, 0.005, 0.09])])
    delta_u = np.array([0.3, 0.1])
    return topo_positions, topo_headings, delta_p, heading_sigma, np.array(HALF_PI), np.array([1.0, 2.0]), dr_poses, dr_cov, delta_u


def test_eq15_eq23_fused_positions_are_midpoints():
    """Eq. 15: R(pi/2) (1, 0) + (1, 2) = (0, 1) + (1, 2) = (1, 3); R(pi/2) (0, 2) + (1, 2) = (-2, 0) + (1, 2) = (-1, 2).

    Eq. 23 (midpoint with dead reckoning (3, 3) and (0, 1)): (2, 3) and (-0.5, 1.5).
    Weights 0.6/0.4 would give (1.8, 3); a rotation by -pi/2 would put the topology at (1, 1) and (3, 2).
    """
    poses, _ = fuse(*_fuse_case())
    np.testing.assert_allclose(poses[:, :2], [[2.0, 3.0], [-0.5, 1.5]], atol=1e-12)


def test_eq23_fused_headings_are_circular_midpoints():
    """Robot 0: topology heading 0.4 + theta pi/2 = pi/2 + 0.4, dead reckoning pi/2: midpoint pi/2 + 0.2.

    (0.6 instead of 0.5 would give pi/2 + 0.24.) Robot 1 observed nobody (NaN): keeps 0.3.
    """
    poses, _ = fuse(*_fuse_case())
    np.testing.assert_allclose(poses[:, 2], [HALF_PI + 0.2, 0.3], atol=1e-12)


def test_eq23_heading_midpoint_across_pi():
    """Topology heading 3.0 (theta 0), dead reckoning -2.9: the short way round is -0.3832 rad
    (wrap(3.0 + 2.9) = 5.9 - 2 pi), so the midpoint is -2.9 - 0.1916 = -3.0916, not the
    arithmetic mean 0.05 (which points the other way)."""
    args = list(_fuse_case())
    args[1] = np.array([3.0, np.nan])
    args[4] = np.array(0.0)
    args[6] = np.array([[3.0, 3.0, -2.9], [0.0, 1.0, 0.3]])
    poses, _ = fuse(*args)
    assert poses[0, 2] == pytest.approx(-2.9 + 0.5 * (5.9 - 2 * math.pi), abs=1e-12)


def test_eq23_fused_covariance():
    """The mean of two independent estimates has variance (delta_u^2 + delta_p^2) / 4, split over x and y.

    Robot 0: (0.3^2 + 0.1^2) / 4 = 0.025 m^2 -> var_x = var_y = 0.0125; heading (0.04 + 0.1^2)/4 = 0.0125.
    Robot 1: (0.1^2 + 0.2^2) / 4 = 0.0125 -> 0.00625 each; no topology heading: keeps 0.09.
    (Dividing by 2 instead of 4 doubles every position variance.)
    """
    _, cov = fuse(*_fuse_case())
    np.testing.assert_allclose(cov[0], np.diag([0.0125, 0.0125, 0.0125]), atol=1e-15)
    np.testing.assert_allclose(cov[1], np.diag([0.00625, 0.00625, 0.09]), atol=1e-15)


def test_fuse_is_batched_over_leading_axes():
    """A batch of two copies, the second with theta = 0 and t = 0: robot 0's topology (1, 0) and
    dead reckoning (3, 3) give (2, 1.5); the first copy is unchanged."""
    case = _fuse_case()
    batched = [np.stack([a, a]) for a in case]
    batched[4] = np.array([HALF_PI, 0.0])
    batched[5] = np.array([[1.0, 2.0], [0.0, 0.0]])
    poses, cov = fuse(*batched)
    single, single_cov = fuse(*case)
    np.testing.assert_allclose(poses[0], single, atol=1e-15)
    np.testing.assert_allclose(cov[1], single_cov, atol=1e-15)
    np.testing.assert_allclose(poses[1, 0, :2], [2.0, 1.5], atol=1e-12)


def test_paper_localizer_end_to_end_known_answer():
    """Exact sensing, exact motion: the fused estimate is the truth whatever the weights.

    Three robots; robot 0 (mobile) commanded from (0, 0, 0) to (0.2, 0) by turn 0, drive 0.2; anchors at
    (0.3, 0.2, pi/2) and (0, 0.3, pi). Dead reckoning = truth; the topology (exact) mapped by Eq. 21
    lands on the truth; Eq. 23 averages two equal points. The covariance is (delta_u^2 + delta_p^2)/8 per axis.
    """
    cfg = ModelConfig(range_sigma_m=0.0, bearing_sigma_rad=0.0, turn_sigma_rad=0.0, drive_sigma_frac=0.0)
    prior = SwarmEstimate.isotropic(np.array([0, 1, 2]), np.array([[0.0, 0.0, 0.0], [0.3, 0.2, HALF_PI], [0.0, 0.3, math.pi]]), 0.02, 0.01)
    step = StepCommands(np.array([0, 1, 2]), np.array([[0.0, 0.2], [0.0, 0.0], [0.0, 0.0]]), np.array([True, False, False]))
    truth = np.array([[0.2, 0.0, 0.0], [0.3, 0.2, HALF_PI], [0.0, 0.3, math.pi]])
    pairs = [(a, b) for a in range(3) for b in range(3) if a != b]
    obs = Observations(*_exact_observations(truth, pairs))
    out = PaperLocalizer(cfg).localize(prior, step, obs)
    np.testing.assert_allclose(out.poses[:, :2], truth[:, :2], atol=1e-9)
    np.testing.assert_allclose(np.cos(out.poses[:, 2] - truth[:, 2]), 1.0, atol=1e-12)
    # exact sensing: every cluster spread is 0 and the single-observation floor is 0 too, so delta_p = 0.
    # Anchors: delta_u = the prior delta 0.02, var per axis 0.02^2 / 4 / 2 = 5e-5. The mover also carries its
    # prior heading error 0.01 rad over 0.2 m across its path: delta_u^2 = 0.02^2 + (0.2 x 0.01)^2 = 4.04e-4 -> 5.05e-5.
    np.testing.assert_allclose(out.cov[:, 0, 0], [5.05e-5, 5e-5, 5e-5], rtol=1e-9)
    np.testing.assert_allclose(out.cov[:, 1, 1], [5.05e-5, 5e-5, 5e-5], rtol=1e-9)


# -- The joint formulation's residuals (range_bearing.py) -------------------------------------


def test_observation_residuals_known_answer():
    """Observer r0 at (0, 0, 0.5), r1 at (3, 4, 0); measured rho 4.9, phi 0.4 with s_r = 0.01, s_b = 0.02.

    Range residual (5 - 4.9) / 0.01 = 10; bearing residual (atan2(4, 3) - 0.5 - 0.4) / s_b(4.9)
    = (0.927295 - 0.9) / s_b(4.9) = 1.36476 / k, where the bearing sigma grows at short range
    (docs/localization.md): s_b(rho) = s_b sqrt(1 + (3 s_r / rho)^4), k = sqrt(1 + (0.03 / 4.9)^4)
    = 1 + 7.0e-10 at this range. Jacobian of the range row w.r.t. r1's (x, y):
    (3/5, 4/5) / 0.01 = (60, 80), w.r.t. r0's: (-60, -80); the bearing row w.r.t. r1:
    (-4/25, 3/25) / 0.02 / k = (-8, 6) / k, w.r.t. r0's heading: -1/0.02 / k = -50 / k.
    """
    poses = np.array([[0.0, 0.0, 0.5], [3.0, 4.0, 0.0]])
    layout = PoseLayout(np.array([True, True]), np.array([True, True]))
    r, (rows, cols, vals) = observation_terms(poses, layout, np.array([0]), np.array([1]), np.array([4.9]), np.array([0.4]), SENSING)
    k = math.sqrt(1 + (3 * 0.01 / 4.9) ** 4)
    np.testing.assert_allclose(r, [10.0, (math.atan2(4, 3) - 0.9) / 0.02 / k], rtol=1e-12)
    dense = np.zeros((2, layout.size))
    np.add.at(dense, (rows, cols), vals)
    np.testing.assert_allclose(dense, [[-60, -80, 0, 60, 80, 0], np.array([8, -6, -50, -8, 6, 0]) / k], atol=1e-9)


def test_bearing_residual_is_wrapped():
    """Observed bearing pi - 0.1 of a robot truly at bearing -pi + 0.1: the residual is 0.2 / s_b(1 m), not
    (2 pi - 0.2) / s_b(1 m); at 1 m, s_b(rho) = 0.02 sqrt(1 + 0.03^4) (short-range weighting)."""
    poses = np.array([[0.0, 0.0, 0.0], [math.cos(-math.pi + 0.1), math.sin(-math.pi + 0.1), 0.0]])
    layout = PoseLayout(np.array([False, True]), np.array([False, True]))
    r, _ = observation_terms(poses, layout, np.array([0]), np.array([1]), np.array([1.0]), np.array([math.pi - 0.1]), SENSING)
    np.testing.assert_allclose(r, [0.0, 0.2 / (0.02 * math.sqrt(1 + 0.03**4))], atol=1e-9)


def test_sqrt_information_whitens_a_known_covariance():
    """cov = diag(4, 1, 0.25) -> W^T W = diag(1/4, 1, 4); a singular cov is floored at COV_FLOOR."""
    w = sqrt_information(np.array([np.diag([4.0, 1.0, 0.25]), np.diag([1.0, 1.0, 0.0])]))
    np.testing.assert_allclose(w[0].T @ w[0], np.diag([0.25, 1.0, 4.0]), atol=1e-12)
    np.testing.assert_allclose(w[1].T @ w[1], np.diag([1.0, 1.0, 1.0 / COV_FLOOR]), rtol=1e-9)


def test_prior_residuals_wrap_the_heading_and_stack_offsets_rows():
    """Prior mean (1, 2, pi - 0.05), pose (1.5, 2, -pi + 0.05), cov diag(0.25, 1, 0.01): W = diag(2, 1, 10).

    The heading difference wraps to 0.1 (not 0.1 - 2 pi), so |W (p - mu)|^2 = (p - mu)^T P^-1 (p - mu)
    = 0.5^2 / 0.25 + 0 + 0.1^2 / 0.01 = 2, and the residuals are 2 x 0.5 = 1, 0 and 10 x 0.1 = 1 (in the
    eigenvector order W uses). Stacked after an observation block of 2 rows, the prior rows are 2, 3, 4 and
    their Jacobian J satisfies J^T J = W^T W = diag(4, 1, 100).
    """
    layout = PoseLayout(np.array([True]), np.array([True]))
    w = sqrt_information(np.array([np.diag([0.25, 1.0, 0.01])]))
    r, triplets = prior_terms(np.array([[1.5, 2.0, -math.pi + 0.05]]), layout, np.array([[1.0, 2.0, math.pi - 0.05]]), w)
    assert float(r @ r) == pytest.approx(2.0, abs=1e-9)
    np.testing.assert_allclose(np.sort(np.abs(r)), [0.0, 1.0, 1.0], atol=1e-9)
    obs_block = (np.array([7.0, 8.0]), (np.array([0, 1]), np.array([0, 1]), np.array([1.0, 1.0])))
    residual, jac = stack_terms(layout.size, obs_block, (r, triplets))
    np.testing.assert_allclose(residual, [7.0, 8.0, *r])
    assert jac.shape == (5, 3)
    prior_rows = (jac.toarray() if hasattr(jac, "toarray") else np.asarray(jac))[2:]  # dense for small problems
    np.testing.assert_allclose(prior_rows.T @ prior_rows, np.diag([4.0, 1.0, 100.0]), atol=1e-9)


def test_sensor_sigmas_are_floored_for_exact_sensing():
    assert sensor_sigmas(ModelConfig(range_sigma_m=0.0, bearing_sigma_rad=0.0)) == (1e-9, 1e-9)
    assert sensor_sigmas(SENSING) == (0.01, 0.02)


def test_relaxed_start_is_exact_on_exact_data():
    """The linear relaxation of Eq. B3 in (x, y, cos theta, sin theta) has the true poses as its
    zero-residual solution when the data are exact, so the solver's start is already the answer:
    the three robots of the test above, (0, 0, 0), (2, 0, -pi/2), (0, 2, pi/2) in r0's frame; and
    with robot 0 observing nobody (gauge robot 1): r0 at (0, 1) with heading 0 (none to solve for)."""
    from coordinator.localization.topology import _relaxed_start

    poses = np.array([[1.0, 1.0, HALF_PI], [1.0, 3.0, 0.0], [-1.0, 1.0, math.pi]])
    pairs = [(a, b) for a in range(3) for b in range(3) if a != b]
    i, j, rho, phi = _exact_observations(poses, pairs)
    start = _relaxed_start(3, i, j, observation_offsets(rho, phi), np.ones(3, bool), 0)
    np.testing.assert_allclose(start, [[0, 0, 0], [2, 0, -HALF_PI], [0, 2, HALF_PI]], atol=1e-6)
    i, j = np.array([1, 1, 2]), np.array([0, 2, 1])
    z = observation_offsets(np.ones(3), np.array([HALF_PI, 0.0, 0.0]))
    start = _relaxed_start(3, i, j, z, np.array([False, True, True]), 1)
    np.testing.assert_allclose(start[:, :2], [[0, 1], [0, 0], [1, 0]], atol=1e-6)
    assert start[0, 2] == 0.0 and start[1, 2] == 0.0 and abs(abs(start[2, 2]) - math.pi) < 1e-6


def test_robust_topology_leaves_a_gross_outlier_out_of_its_cluster():
    """Exact observations of the three-robot triangle plus one gross outlier: r1 also reports r2 2 m too far.

    With ``huber`` = 0.05 m the solution stays near the truth and the outlier's point, ~2 m from
    robot 2's solved position (> 2 x huber), leaves r2's cluster: r2's topology position is the
    centroid of the good observations, (0, 2). Without ``huber`` the outlier stays in the cluster
    and drags r2's centroid by about 2 m / 3 towards it.
    """
    poses = np.array([[1.0, 1.0, HALF_PI], [1.0, 3.0, 0.0], [-1.0, 1.0, math.pi]])
    pairs = [(a, b) for a in range(3) for b in range(3) if a != b]
    i, j, rho, phi = _exact_observations(poses, pairs)
    k = pairs.index((1, 2))
    i, j, rho, phi = np.append(i, 1), np.append(j, 2), np.append(rho, rho[k] + 2.0), np.append(phi, phi[k])
    robust = estimate_topology(3, i, j, rho, phi, SENSING, huber=0.05)
    np.testing.assert_allclose(robust.positions, [[0, 0], [2, 0], [0, 2]], atol=0.02)
    plain = estimate_topology(3, i, j, rho, phi, SENSING)
    assert np.linalg.norm(plain.positions[2] - [0.0, 2.0]) > 0.3


def test_the_paper_localizer_hands_its_huber_threshold_to_the_topology():
    """The triangle with the gross outlier of the test above: ``PaperLocalizer(cfg, huber=0.05).topology`` is
    ``estimate_topology(..., huber=0.05)``, near the truth (least squares is ~2/3 m off for r2)."""
    poses = np.array([[1.0, 1.0, HALF_PI], [1.0, 3.0, 0.0], [-1.0, 1.0, math.pi]])
    pairs = [(a, b) for a in range(3) for b in range(3) if a != b]
    i, j, rho, phi = _exact_observations(poses, pairs)
    k = pairs.index((1, 2))
    i, j, rho, phi = np.append(i, 1), np.append(j, 2), np.append(rho, rho[k] + 2.0), np.append(phi, phi[k])
    paper = PaperLocalizer(SENSING, huber=0.05).topology(np.arange(3), Observations(i, j, rho, phi))
    np.testing.assert_allclose(paper.positions, estimate_topology(3, i, j, rho, phi, SENSING, huber=0.05).positions, atol=1e-12)
    np.testing.assert_allclose(paper.positions, [[0, 0], [2, 0], [0, 2]], atol=0.02)


def test_robust_topology_drops_an_outlier_beside_a_single_good_point():
    """As above, but r0 does not observe r2: r2's cluster has one good point (from r1) and the outlier. The
    outlier still leaves it (one inlier remains; only a robot with no inlier at all keeps its outliers), so
    r2's topology position is the good point (0, 2), not the midpoint about 1 m away."""
    poses = np.array([[1.0, 1.0, HALF_PI], [1.0, 3.0, 0.0], [-1.0, 1.0, math.pi]])
    pairs = [(a, b) for a in range(3) for b in range(3) if a != b and (a, b) != (0, 2)]
    i, j, rho, phi = _exact_observations(poses, pairs)
    k = pairs.index((1, 2))
    i, j, rho, phi = np.append(i, 1), np.append(j, 2), np.append(rho, rho[k] + 2.0), np.append(phi, phi[k])
    robust = estimate_topology(3, i, j, rho, phi, SENSING, huber=0.05)
    np.testing.assert_allclose(robust.positions, [[0, 0], [2, 0], [0, 2]], atol=0.02)


def test_topology_no_convergence_is_reported(monkeypatch):
    """A solver allowed one iteration (no convergence test) does not converge: 'no-convergence', no robots
    named, with the topology's message."""
    import coordinator.localization.topology as topology_module

    real = topology_module.levenberg_marquardt
    monkeypatch.setattr(topology_module, "levenberg_marquardt",
                        lambda *a, **kw: real(*a, **{**kw, "max_iter": 1, "xtol": 0.0, "ftol": 0.0}))
    poses = np.array([[1.0, 1.0, HALF_PI], [1.0, 3.0, 0.0], [-1.0, 1.0, math.pi]])
    i, j, rho, phi = _exact_observations(poses, [(a, b) for a in range(3) for b in range(3) if a != b])
    with pytest.raises(LocalizationError) as err:
        estimate_topology(3, i, j, rho + 0.05 * np.arange(len(rho)), phi, SENSING)
    assert str(err.value) == "no-convergence: robots [] (topology least squares did not converge)"


def test_crlb_known_answer_for_one_observation():
    """Robot 0 at (0, 0, 0) known almost exactly (prior variances 1e-10), robot 1 at (2, 0, 0.3) barely
    (prior variances 100); robot 0 measures robot 1 (s_r = 0.01 m, s_b = 0.02 rad).

    Fisher information on robot 1's position: the range row's gradient is (1, 0) / s_r, the bearing
    row's (-dy, dx) / d^2 / s_b = (0, 1/2) / 0.02, so I = diag(1e4, 625) + the prior's 0.01: the bound
    is diag(1 / (1e4 + 0.01), 1 / (625 + 0.01)) ~ diag(s_r^2, (d s_b)^2) = diag(1e-4, 1.6e-3) m^2; robot 1's heading is unobserved (stays 100 rad^2)
    and robot 0 keeps its prior. Without observations the bound is the prior itself.
    """
    from coordinator.localization.crlb import crlb_pose_covariances

    poses = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.3]])
    prior = np.stack([np.eye(3) * 1e-10, np.eye(3) * 100.0])
    cov = crlb_pose_covariances(poses, prior, np.array([0]), np.array([1]), SENSING)
    np.testing.assert_allclose(np.diag(cov[1]), [1 / (1e4 + 0.01), 1 / (625 + 0.01), 100.0], rtol=1e-6)
    np.testing.assert_allclose(np.diag(cov[0]), [1e-10] * 3, rtol=1e-5)
    alone = crlb_pose_covariances(poses, prior, np.array([], dtype=int), np.array([], dtype=int), SENSING)
    np.testing.assert_allclose(alone, prior, rtol=1e-9)
