"""The Python API seen from fresh processes: an unknown study-file key is one line from the CLI; importing the library
and the CLI sets no BLAS variable and chooses no matplotlib backend."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_the_cli_names_an_unknown_study_file_key_in_one_line(tmp_path):
    (tmp_path / "s.toml").write_text("trajectories = 2\nlocaliser = 'joint'\n")
    out = subprocess.run([sys.executable, "-m", "swarm_cli.main", "compare", "--config", str(tmp_path / "s.toml"), "--out", str(tmp_path)],
                         capture_output=True, text=True, cwd=REPO, timeout=120)
    assert out.returncode == 2 and out.stderr.strip().splitlines() == [f"swarm: error: --config {tmp_path / 's.toml'}: unknown key 'localiser'"]
    assert not (tmp_path / "runs.jsonl").exists()


def test_importing_the_library_and_the_cli_changes_nothing():
    """No BLAS variables set, no matplotlib backend chosen, pyplot not loaded, by importing."""
    code = ("import os, sys, inchworm, inchworm.plots, inchworm.comparison, inchworm.studies.anchors, swarm_cli, swarm_cli.main\n"
            "assert not [v for v in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS') if v in os.environ]\n"
            "assert 'matplotlib.pyplot' not in sys.modules\n"
            "import matplotlib; assert matplotlib.rcParams._get_backend_or_none() is None, matplotlib.rcParams._get_backend_or_none()\n")
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "MPLBACKEND")}
    subprocess.run([sys.executable, "-c", code], check=True, cwd=REPO, env=env, timeout=120)


