"""Chance constraint of robot bodies: an upper bound on the probability that two robots touch during a step.

Model (``docs/bodies.md``). Robot i's pose at the start of a configuration change is Gaussian (the estimate:
mean m_i, 3x3 covariance P_i, cross-covariances P_ij when the joint covariance is known). Its move is the
turn-then-drive command towards its desired position; at normalised time s of its drive its position has the
exact moments of that command with the drive scaled by s (``runtime.models.motion.motion_moments``: the drive's
relative error and the heading error act on the distance driven so far), so with t = s while it drives
(t = 0 before, t = 1 after its move):

    mean   x_i(t) = m_i + t a_i,                    a_i = d_i k_i u_i  (k_i = exp(-s_phi^2 / 2) <= 1)
    cov    C_i(t) = P_pp + t (f_i P_tp + P_pt f_i^T) + t^2 (P_tt f_i f_i^T + W_i)
    cross  X_ij(t_i, t_j) = P_ij,pp + t_i f_i P_ij,tp + t_j P_ij,pt f_j^T + t_i t_j P_ij,tt f_i f_j^T

(f_i = d_i k_i (-sin, cos) of the commanded heading: how a heading error swings the path; W_i the part of the
motion's covariance the pre-step pose does not explain). In a step every mover has t = s, s in [0, 1] (they
start and arrive together), every other robot a fixed t in {0, 1}, so a pair's relative position
r(s) = x_i - x_j has mean mu(s) = mu_0 + s v and covariance Sigma(s) = S_0 + s S_1 + s^2 S_2
(C_i + C_j - X_ij - X_ij^T), treated as Gaussian.

Bound. The bodies (discs of radius R) touch when |r| < rho = 2R. The disc lies in every half-plane
H_w = {x : w.x <= rho |w|}, so for a Gaussian r, P(|r| < rho) <= P(r in H_w) = Phi(-g(w)) with
g(w) = (w.mu - rho |w|) / sqrt(w^T Sigma w), for any w (the best w gives the Mahalanobis distance of the disc).
Over a time interval [s_a, s_b] each realisation's relative position moves on a straight segment (the true motion
is turn-then-drive with the timing above), and a segment that enters the disc enters H_w, which needs one of its
ends in H_w: P(contact in [s_a, s_b]) <= Phi(-g_a(w)) + Phi(-g_b(w)) for one w. The bound of a step is the smaller
of (one interval) and (the sum over ``INTERVALS`` equal intervals), each interval with the best of the directions
w = (Sigma_c + c tau I)^-1 mu_c, c in ``SHAPES`` (tau = tr Sigma_c / 2, c = inf: w = mu_c), mu_c and Sigma_c at the
interval's closest mean approach: the family holds the optimal separating direction for some c. A pair with no
mover is one instant: Phi(-g). Everything is vectorised over pairs; the only approximation is the Gaussian
relative position (its moments are exact up to the cross term's first order).
"""

from __future__ import annotations

import functools

import numpy as np

from runtime.models.config import ModelConfig
from runtime.models.motion import motion_moments

INTERVALS = 8  # equal time intervals of a step in the finer of the two bounds (split again at the closest mean approach)
SHAPES = (0.0, 1.0, np.inf)  # c of the directions w = (Sigma + c tau I)^-1 mu tried (inf: w = mu)


def _phi_upper(g: np.ndarray) -> np.ndarray:
    """Phi(-g), the standard normal's upper tail at g."""
    from scipy.special import ndtr  # noqa: PLC0415 - scipy only when bodies are checked (cheap parsers)

    return np.asarray(ndtr(-g), dtype=float)


def _directions(mu: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(..., len(SHAPES), 2) directions w = (sigma + c tau I)^-1 mu of ``mu`` (..., 2), ``sigma`` (..., 2, 2)."""
    tau = 0.5 * (sigma[..., 0, 0] + sigma[..., 1, 1])
    out = []
    for c in SHAPES:
        if np.isinf(c):
            out.append(mu)
            continue
        a = sigma[..., 0, 0] + c * tau
        d = sigma[..., 1, 1] + c * tau
        b = sigma[..., 0, 1]
        det = a * d - b * b  # adjugate: the scale of w does not matter, only a degenerate sigma does
        w = np.stack([d * mu[..., 0] - b * mu[..., 1], a * mu[..., 1] - b * mu[..., 0]], axis=-1)
        out.append(np.where((det > 0)[..., None], w, mu))
    return np.stack(out, axis=-2)


def _margin(w: np.ndarray, mu: np.ndarray, sigma: np.ndarray, rho: float) -> np.ndarray:
    """g(w) = (w.mu - rho |w|) / sqrt(w^T sigma w) for directions ``w`` (..., m, 2) against ``mu`` (..., 2),
    ``sigma`` (..., 2, 2) broadcast over m: +inf where the spread along w is 0 and the mean is outside H_w,
    -inf where inside; -inf for w = 0 (a mean at the disc's centre: no half-plane helps)."""
    w0, w1 = w[..., 0], w[..., 1]
    norm = np.hypot(w0, w1)
    num = w0 * mu[..., None, 0] + w1 * mu[..., None, 1] - rho * norm
    spread = w0 * w0 * sigma[..., None, 0, 0] + 2.0 * w0 * w1 * sigma[..., None, 0, 1] + w1 * w1 * sigma[..., None, 1, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        g = num / np.sqrt(np.maximum(spread, 0.0))
    g = np.where(spread > 0, g, np.where(num > 0, np.inf, -np.inf))
    return np.where(norm > 0, g, -np.inf)


def instant_bound(mu: np.ndarray, sigma: np.ndarray, rho: float) -> np.ndarray:
    """Upper bound of P(|r| < ``rho``) for r ~ N(``mu`` (m, 2), ``sigma`` (m, 2, 2)): min over the directions of
    Phi(-g(w))."""
    w = _directions(mu, sigma)
    return np.asarray(np.minimum(_phi_upper(_margin(w, mu, sigma, rho)).min(axis=-1), 1.0))


DISC_NODES = 128  # Gauss-Legendre nodes of ``disc_probability``'s integral over the disc
EXACT_MIN_SD = 0.1  # ``disc_probability`` integrates where the larger standard deviation is at least this x rho


@functools.cache
def _disc_quadrature() -> tuple[np.ndarray, np.ndarray]:
    """The ``DISC_NODES`` Gauss-Legendre nodes and weights on [-1, 1], computed once (each computation solves for the
    roots of a Legendre polynomial: 1-3 ms, which every ``disc_probability`` call paid before), read-only."""
    nodes, weights = np.polynomial.legendre.leggauss(DISC_NODES)
    nodes.flags.writeable = weights.flags.writeable = False
    return nodes, weights


def disc_probability(mu: np.ndarray, sigma: np.ndarray, rho: float) -> np.ndarray:
    """P(|r| < ``rho``) for r ~ N(``mu`` (m, 2), ``sigma`` (m, 2, 2)), to about 1e-6 relative: in the principal axes of
    ``sigma`` (x the narrower, y the wider) the disc is the y-interval |y| <= rho cos(theta) at x = rho sin(theta), so
    the probability is one smooth integral over theta of the x density times the y interval's Gaussian mass
    (Gauss-Legendre, ``DISC_NODES``, over the part of the disc within 9 standard deviations of the mean in x). Where
    the wider standard deviation is below ``EXACT_MIN_SD`` rho (a near step function over the disc) it is
    ``instant_bound``, an upper bound."""
    from scipy.special import ndtr  # noqa: PLC0415 - scipy only when bodies are checked (cheap parsers)

    mu, sigma = np.asarray(mu, float), np.asarray(sigma, float)
    out = instant_bound(mu, sigma, rho) if len(mu) else np.zeros(0)
    vals, vecs = np.linalg.eigh(sigma)  # ascending: column 0 the narrower axis
    sx, sy = np.sqrt(np.maximum(vals[:, 0], 0.0)), np.sqrt(np.maximum(vals[:, 1], 0.0))
    mx, my = np.einsum("mk,mk->m", vecs[:, :, 0], mu), np.einsum("mk,mk->m", vecs[:, :, 1], mu)
    lo, hi = np.maximum(mx - 9.0 * sx, -rho), np.minimum(mx + 9.0 * sx, rho)
    exact = (sy >= EXACT_MIN_SD * rho) & (sx > 0)
    out[exact & (lo >= hi)] = 0.0  # the disc is more than 9 sd away in x
    k = np.flatnonzero(exact & (lo < hi))
    if not len(k):
        return out
    a, b = np.arcsin(lo[k] / rho), np.arcsin(hi[k] / rho)
    nodes, weights = _disc_quadrature()
    half = 0.5 * (b - a)
    theta = (a + b)[:, None] * 0.5 + half[:, None] * nodes[None]
    x, h = rho * np.sin(theta), rho * np.cos(theta)
    zx = (x - mx[k, None]) / sx[k, None]
    density = np.exp(-0.5 * zx * zx) / (np.sqrt(2.0 * np.pi) * sx[k, None])
    mass = ndtr((h - my[k, None]) / sy[k, None]) - ndtr((-h - my[k, None]) / sy[k, None])
    out[k] = np.minimum(half * ((density * h * mass) @ weights), 1.0)
    return np.asarray(out)


def _at(s: np.ndarray, mu0: np.ndarray, v: np.ndarray, quad: tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(mu(s), Sigma(s)) for times ``s`` (m, k): (m, k, 2), (m, k, 2, 2)."""
    s0, s1, s2 = quad
    t = s[..., None]
    mu = mu0[:, None] + t * v[:, None]
    tt = t[..., None]
    return mu, s0[:, None] + tt * s1[:, None] + tt * tt * s2[:, None]


def step_bound(mu0: np.ndarray, v: np.ndarray, s0: np.ndarray, s1: np.ndarray, s2: np.ndarray, rho: float,
               moving: np.ndarray | None = None, enough: np.ndarray | float = 0.0) -> np.ndarray:
    """Upper bound (m,) of the probability that a pair's relative position r(s), mean ``mu0`` + s ``v`` (m, 2) and
    covariance ``s0`` + s ``s1`` + s^2 ``s2`` (m, 2, 2), comes within ``rho`` of the origin for some s in [0, 1]
    (module docstring). ``moving`` (m,) False: the pair has no mover (one instant). Pairs whose first, coarse bound
    (the whole step, w along its closest mean approach) is at most ``enough`` (m,) keep that bound (a caller that
    only compares with ``enough`` needs no finer one)."""
    m = len(mu0)
    out = np.zeros(m)
    if not m:
        return out
    moving = np.ones(m, bool) if moving is None else np.asarray(moving, bool)
    vv = np.einsum("mk,mk->m", v, v)
    s_star = np.clip(-np.einsum("mk,mk->m", mu0, v) / np.where(vv > 0, vv, 1.0), 0.0, 1.0)  # closest mean approach
    ends = np.array([0.0, 1.0])
    mu_c = mu0 + s_star[:, None] * v
    mu_t, sig_t = _at(np.broadcast_to(ends, (m, 2)), mu0, v, (s0, s1, s2))
    coarse = _phi_upper(_margin(mu_c[:, None, None, :], mu_t, sig_t, rho))[..., 0]  # (m, 2)
    out[:] = np.where(moving, coarse.sum(axis=1), coarse[:, 0])
    fine = np.flatnonzero(out > enough)
    still = fine[~moving[fine]]
    if len(still):
        out[still] = np.minimum(out[still], instant_bound(mu0[still], s0[still], rho))
    go = fine[moving[fine]]
    if len(go):
        out[go] = np.minimum(out[go], _intervals(mu0[go], v[go], (s0[go], s1[go], s2[go]), rho))
    return np.minimum(out, 1.0)


def _intervals(mu0: np.ndarray, v: np.ndarray, quad: tuple[np.ndarray, np.ndarray, np.ndarray], rho: float) -> np.ndarray:
    """The bound of ``step_bound`` from the whole step and from its ``INTERVALS`` parts (split again at the closest
    mean approach), each interval with its best direction."""
    m = len(mu0)
    vv = np.einsum("mk,mk->m", v, v)
    s_star = np.clip(-np.einsum("mk,mk->m", mu0, v) / np.where(vv > 0, vv, 1.0), 0.0, 1.0)
    grid = np.sort(np.concatenate([np.broadcast_to(np.linspace(0.0, 1.0, INTERVALS + 1), (m, INTERVALS + 1)), s_star[:, None]], axis=1), axis=1)
    starts = np.concatenate([np.zeros((m, 1)), grid[:, :-1]], axis=1)  # interval 0 is the whole step, then the parts
    ends = np.concatenate([np.ones((m, 1)), grid[:, 1:]], axis=1)
    mu_a = mu0[:, None] + starts[..., None] * v[:, None]
    closest = np.clip(-np.einsum("mik,mk->mi", mu_a, v) / np.where(vv > 0, vv, 1.0)[:, None], 0.0, None)
    s_c = np.minimum(starts + closest, ends)  # each interval's closest mean approach
    mu_c, sig_c = _at(s_c, mu0, v, quad)
    w = _directions(mu_c, sig_c)  # (m, intervals, shapes, 2)
    mu_s, sig_s = _at(starts, mu0, v, quad)
    mu_e, sig_e = _at(ends, mu0, v, quad)
    per = np.minimum(_phi_upper(_margin(w, mu_s, sig_s, rho)) + _phi_upper(_margin(w, mu_e, sig_e, rho)), 1.0).min(axis=-1)
    per[:, 1:] = np.where(ends[:, 1:] > starts[:, 1:], per[:, 1:], 0.0)  # an empty part (s* on the grid) adds nothing
    return np.asarray(np.minimum(per[:, 0], per[:, 1:].sum(axis=1)))


class MotionMoments:
    """Each robot's position moments over its single move of a configuration change (module docstring): from
    ``current`` (n, 2) m to ``desired`` (n, 2) m, pose covariance ``cov`` (n, 3, 3) at the start, the joint
    (3n, 3n) covariance ``joint`` for the cross terms (None: robots uncorrelated)."""

    def __init__(self, cfg: ModelConfig, current: np.ndarray, desired: np.ndarray, cov: np.ndarray,
                 joint: np.ndarray | None = None) -> None:
        n = len(current)
        path = desired - current
        poses = np.column_stack([current, np.zeros(n)])  # heading 0: the command's turn only sets the drive's heading
        commands = np.column_stack([np.arctan2(path[:, 1], path[:, 0]), np.hypot(path[:, 0], path[:, 1])])
        mean, fx, noise = motion_moments(poses, cov, commands, cfg)
        self.current = current
        self.step = mean[:, :2] - current  # a_i: the mean displacement of the move (short of the path by k_i)
        self.f = fx[:, :2, 2]  # how a heading error at the start swings the end position
        p_pp, p_tp, p_tt = cov[:, :2, :2], cov[:, 2, :2], cov[:, 2, 2]
        self.c0 = p_pp
        self.c1 = np.einsum("nk,nl->nkl", self.f, p_tp) + np.einsum("nk,nl->nkl", p_tp, self.f)
        self.c2 = p_tt[:, None, None] * np.einsum("nk,nl->nkl", self.f, self.f) + noise[:, :2, :2]
        self.joint = joint

    def spread(self) -> np.ndarray:
        """(n,) a bound of each robot's position standard deviation along any direction at any time of its move
        (m): sqrt of the largest trace of C_i(t), t in [0, 1] (a convex quadratic in t: at an end)."""
        def tr(c: np.ndarray) -> np.ndarray:
            return np.asarray(c[:, 0, 0] + c[:, 1, 1])

        return np.asarray(np.sqrt(np.maximum(tr(self.c0), tr(self.c0) + tr(self.c1) + tr(self.c2))))

    def pairs(self, i: np.ndarray, j: np.ndarray, fixed_i: np.ndarray, moves_i: np.ndarray, fixed_j: np.ndarray,
              moves_j: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(mu_0, v, S_0, S_1, S_2) of the relative positions x_i - x_j of pairs (i, j) whose robots are at
        t = ``fixed`` + s ``moves`` (``fixed`` 0 or 1: before or after their move; ``moves`` 1: moving in the step)."""
        ai, bi = np.asarray(fixed_i, float), np.asarray(moves_i, float)
        aj, bj = np.asarray(fixed_j, float), np.asarray(moves_j, float)
        mu0 = self.current[i] + ai[:, None] * self.step[i] - self.current[j] - aj[:, None] * self.step[j]
        v = bi[:, None] * self.step[i] - bj[:, None] * self.step[j]

        def own(k: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            a3, b3 = a[:, None, None], b[:, None, None]
            return (self.c0[k] + a3 * self.c1[k] + a3 * a3 * self.c2[k], b3 * self.c1[k] + 2 * a3 * b3 * self.c2[k], b3 * b3 * self.c2[k])

        (i0, i1, i2), (j0, j1, j2) = own(i, ai, bi), own(j, aj, bj)
        s0, s1, s2 = i0 + j0, i1 + j1, i2 + j2
        if self.joint is not None and len(i):
            blocks = self.joint[(3 * i)[:, None, None] + np.arange(3)[None, :, None], (3 * j)[:, None, None] + np.arange(3)[None, None, :]]
            fi, fj = self.f[i], self.f[j]
            q = blocks[:, :2, :2]
            ui = np.einsum("mk,ml->mkl", fi, blocks[:, 2, :2])  # f_i P_ij,tp
            uj = np.einsum("mk,ml->mkl", blocks[:, :2, 2], fj)  # P_ij,pt f_j^T
            uu = blocks[:, 2, 2][:, None, None] * np.einsum("mk,ml->mkl", fi, fj)
            a_i, b_i, a_j, b_j = (x[:, None, None] for x in (ai, bi, aj, bj))
            x0 = q + a_i * ui + a_j * uj + a_i * a_j * uu
            x1 = b_i * ui + b_j * uj + (a_i * b_j + b_i * a_j) * uu
            x2 = b_i * b_j * uu
            s0 = s0 - x0 - np.swapaxes(x0, 1, 2)
            s1 = s1 - x1 - np.swapaxes(x1, 1, 2)
            s2 = s2 - x2 - np.swapaxes(x2, 1, 2)
        return mu0, v, s0, s1, s2
