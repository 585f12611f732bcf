"""``swarm bench runtime`` on a tiny swarm: the JSON contract, and no agent process left behind."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}


def _alive_with(text: str) -> list[int]:
    """Pids of processes (zombies excluded) whose command line mentions ``text``."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if text in (entry / "cmdline").read_bytes().decode(errors="replace") and (entry / "stat").read_text().split()[2] != "Z":
                    pids.append(int(entry.name))
            except OSError:
                pass
    return pids


@pytest.mark.parametrize("per_process", [1, 2])
def test_bench_runtime_json_contract_and_cleanup(per_process):
    proc = subprocess.Popen(
        [sys.executable, "-m", "swarm_cli.main", "bench", "runtime", "--agents", "3", "--steps", "3", "--rtt-count", "20", "--json",
         f"--agents-per-process={per_process}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO, env=ENV,
    )
    try:
        stdout, stderr = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            proc.kill()  # its agents would then be orphans: the check below names them
            proc.wait()
    assert proc.returncode == 0, stderr
    last = json.loads(stdout.strip().splitlines()[-1])
    assert list(last) == ["results"] and len(last["results"]) == 1
    row = last["results"][0]
    assert list(row)[:5] == ["agents", "step_ms_median", "zenoh_rtt_ms", "agent_rss_mb", "agents_per_process"]  # the contract
    assert list(row)[5:] == ["breakdown_ms", "cpu_ms_per_step"]  # added keys
    parts = row["breakdown_ms"]
    assert list(parts) == ["commands", "observe", "localize", "publish_estimate"]
    assert all(v >= 0 for v in parts.values()) and 0 < parts["commands"] + parts["observe"] < 2 * row["step_ms_median"]
    # CPU is counted in clock ticks (10 ms): 0 on a run this short
    assert set(row["cpu_ms_per_step"]) == {"agents", "coordinator"} and all(v >= 0 for v in row["cpu_ms_per_step"].values())
    assert row["agents"] == 3 and row["agents_per_process"] == per_process
    # a step is command -> status -> observe request -> observations -> estimate: at least two
    # sequential Zenoh round trips between the coordinator and the agents, so never faster than one
    assert 0 < row["zenoh_rtt_ms"] < row["step_ms_median"]
    # per robot agent: the agent processes (tens of MB each) divided by the agents they host
    assert 10 / per_process < row["agent_rss_mb"] < 1000 / per_process
    assert "3 agents: all alive" in stderr
    assert _alive_with(f"bench-runtime-{proc.pid}-") == []
