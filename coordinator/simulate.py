"""One simulated run: a trajectory, a method, the in-process simulated swarm, one seed.

The true start is the trajectory's initial poses; the initial estimate is the truth
plus an error drawn with the declared uncertainty (``initial_delta`` m,
``initial_heading_sigma`` rad), so the estimate's covariance is honest. Everything
random derives from ``seed``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from coordinator.executor import InchwormExecutor
from coordinator.localization import Localizer, make_localizer
from coordinator.localization.registry import DEFAULT_LOCALIZER
from coordinator.run_result import RunResult
from coordinator.selection.selector import SelectionConfig
from coordinator.strategies import make_strategy
from runtime.models.config import ModelConfig
from runtime.models.simulation import SimulatedSwarm
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import Trajectory, validate_connected, validate_passable


def initial_estimate(traj: Trajectory, seed: int, delta: float, heading_sigma: float) -> SwarmEstimate:
    """The start estimate: truth plus an error drawn from the declared uncertainty."""
    rng = np.random.default_rng([seed, 3])
    n = traj.n
    poses = traj.initial_poses.copy()
    poses[:, :2] += rng.normal(0.0, delta / math.sqrt(2.0), (n, 2))
    poses[:, 2] += rng.normal(0.0, heading_sigma, n)
    return SwarmEstimate.isotropic(traj.ids, poses, delta, heading_sigma)


def simulate(
    traj: Trajectory,
    method: str,
    cfg: ModelConfig,
    *,
    localizer: str | Localizer = DEFAULT_LOCALIZER,
    selection: SelectionConfig = SelectionConfig(),
    seed: int = 0,
    initial_delta: float = 0.01,
    initial_heading_sigma: float = math.radians(2.0),
    progress: Callable[[int, int], None] | None = None,
) -> RunResult:
    """Run ``method`` along ``traj`` in the in-process simulator. ``localizer``: a registered name
    (``registry.localizer_names``) or a localizer object; the executor and the anchor selection use the same one."""
    validate_connected(traj, cfg.sensing_range_m)
    validate_passable(traj, cfg)
    loc = make_localizer(localizer, cfg) if isinstance(localizer, str) else localizer
    backend = SimulatedSwarm(traj.ids, traj.initial_poses, cfg, seed)
    strategy = make_strategy(method, traj.n, cfg, loc, selection, seed)
    executor = InchwormExecutor(backend, loc, strategy, cfg, progress)
    return executor.run(traj, initial_estimate(traj, seed, initial_delta, initial_heading_sigma))
