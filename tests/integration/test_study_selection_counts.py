"""``study selection``'s best count is one the search may return: n_a = 0 only where its one step is clear."""

from __future__ import annotations

import numpy as np

from coordinator.plan import Plan
from coordinator.selection.selector import SelectionConfig
from inchworm.studies.anchors import Job, experiment_setup
from inchworm.studies.selection import Budget, ConfigTask, run_config
from runtime.models.bodies import BodyCheck
from runtime.models.config import ModelConfig


def test_a_crowded_all_move_step_is_never_the_best_count():
    """Configuration 0 of seed 4242 (8 robots, default radius): every robot moving at once brings two too close, so the
    online search cannot choose n_a = 0 and the study's reference must not either (it did: 'n_a disagrees')."""
    cfg = ModelConfig()
    job = Job(0, 8, 2, 4242, cfg, "joint", exhaustive=False)
    _, _, desired, estimate, _ = experiment_setup(job)
    assert not BodyCheck.of_estimate(cfg, estimate, desired).is_clear(Plan.equal(np.arange(8), 0).groups)
    selection = SelectionConfig(samples=2, final_samples=8)
    row = run_config(ConfigTask(job, selection, Budget(2, 4, 8)))
    assert row["na0_clear"] == 0 and row["best_na"] != 0 and row["chosen_na"] != 0
