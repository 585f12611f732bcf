"""An unreachable Dask scheduler is a one-line error and exit 2 (`swarm compare --scheduler` as a subprocess)."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_an_unreachable_scheduler_is_one_line_and_exit_2(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # free, and nobody listens once closed
    proc = subprocess.run([sys.executable, "-m", "swarm_cli.main", "compare", "--trajectories", "1", "--configs", "1",
                           "--scheduler", f"tcp://127.0.0.1:{port}", "--out", str(tmp_path)], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip()]
    assert f"--scheduler tcp://127.0.0.1:{port}: cannot reach a Dask scheduler" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "runs.jsonl").exists()
