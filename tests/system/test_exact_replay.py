"""Exact replay and takeover for every localizer, driver and body setting, with real processes.

One ``swarm launch`` per combination, all 8 (each a real launch with a standby and a killed coordinator, about 6 s
of CPU; 4 robots, 2 configurations, ``ref57``: two steps a configuration, so every localization after the first
starts from a prior the previous step built): its coordinator is SIGKILLed when step 2
starts and the standby takes the run over from the checkpoint after step 1 (``--standby --kill-coordinator 2``).
Then

* ``swarm replay --check`` of the run's recording (the standby's, which holds the whole run) reproduces every
  estimate and plan bit for bit: the check carries its own chain of recomputed estimates from step 0 on, so the
  standby's estimates after the takeover are compared with what one uninterrupted coordinator computes from the
  same inputs;
* the run equals the in-process ``simulate`` of the same trajectory and seed: bit for bit with simulated agents,
  to float32 on the wire (1e-6) through the gateway's emulated robots (docs/gateway-protocol.md).

The joint localizer carries its (3n, 3n) joint covariance from step to step (``SwarmEstimate.joint``), which
neither the recorded ``EstimateMessage`` nor a checkpoint without it holds: without the chain and the checkpoint's
copy, both checks fail at step 2.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from coordinator.replay_check import check, load_recording
from coordinator.simulate import simulate
from runtime.models.config import ModelConfig
from runtime.models.trajectory import body_spacing, random_trajectory

REPO = Path(__file__).resolve().parents[2]
SEED, ROBOTS, CONFIGS, KILL = 3, 4, 2, 2


@pytest.mark.parametrize("bodies", ["bodies", "points"])
@pytest.mark.parametrize("driver", ["sim", "gateway"])
@pytest.mark.parametrize("localizer", ["paper", "joint"])
def test_a_taken_over_run_replays_exactly_and_equals_the_in_process_run(tmp_path, localizer, driver, bodies):
    cfg = ModelConfig() if bodies == "bodies" else ModelConfig(robot_radius_m=0.0)
    traj = random_trajectory(ROBOTS, CONFIGS, np.random.default_rng(SEED), **body_spacing(cfg))
    traj.save(tmp_path / "traj.json")
    radius = [] if bodies == "bodies" else ["--robot-radius=0"]
    proc = subprocess.run(
        [sys.executable, "-m", "swarm_cli.main", "launch", "--trajectory=traj.json", f"--seed={SEED}", "--method=ref57",
         f"--localizer={localizer}", f"--driver={driver}", *radius, "--motion-time=0.05", "--standby", f"--kill-coordinator={KILL}",
         "--record=run.mcap", "--result=result.json", "--out=plots", "--json"],
        capture_output=True, text=True, cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(REPO)}, timeout=180)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "the standby takes over" in proc.stderr, proc.stderr[-3000:]
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["coordinator_kill"]["step"] == KILL and summary["localizer"] == localizer

    rec = load_recording(tmp_path / "run.standby.mcap")
    checked = check(rec)
    ref = simulate(traj, "ref57", cfg, localizer=localizer, seed=SEED)
    assert checked.passed, str(checked.divergence)
    assert checked.exact and checked.skipped == []
    legs = sum(max(len(c.legs) - 1, 0) for c in ref.configs)  # approach legs after the first (docs/bodies.md): plans too
    assert checked.estimates == len(ref.steps) + 1 and checked.plans == CONFIGS + legs  # the initial estimate and every step

    # a recording without step 2's reports: the paper localizer goes on from the recorded estimate of step 2; the
    # joint one cannot (that estimate lacks the joint covariance), and the check says so instead of diverging
    del rec.reports[KILL][0]
    gapped = check(rec)
    assert gapped.passed and gapped.skipped[0] == f"step {KILL} (no observation report from robots [0])"
    if localizer == "paper":
        assert (gapped.estimates, gapped.plans, len(gapped.skipped)) == (len(ref.steps), CONFIGS + legs, 1)
    else:
        assert gapped.estimates == KILL and gapped.plans == 1  # the initial estimate and step 1; configuration 1's plan
        why = (f"the joint localizer carries joint from step to step, which the recording does not hold, and the recomputed "
               f"chain broke at step {KILL} (no observation report from robots [0])")
        assert gapped.skipped[1:] == [f"plans from configuration 2 on ({why})",
                                      f"{len(ref.steps) - KILL} steps from {KILL + 1} to {len(ref.steps)} ({why})"]

    got = json.loads((tmp_path / "result.json").read_text())["steps"]
    assert len(got) == len(ref.steps) > KILL
    exact = driver == "sim"
    for s, r in zip(got, ref.steps, strict=True):
        for key, value in (("poses", r.estimate.poses), ("cov", r.estimate.cov), ("truth", r.truth)):
            if exact:
                np.testing.assert_array_equal(s[key], value, err_msg=key)
            else:
                np.testing.assert_allclose(s[key], value, rtol=0, atol=1e-6, err_msg=key)
