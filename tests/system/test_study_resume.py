"""A study stopped with Ctrl-C keeps its finished runs, and ``--resume`` ends where an uninterrupted study ends
(real ``swarm compare`` subprocesses, small sizes)."""

from __future__ import annotations

import csv
import json
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
COMPARE = ["compare", "--robots", "6", "--trajectories", "4", "--configs", "3", "--methods", "inchworm,ref57,no-anchors",
           "--workers", "2", "--samples", "4", "--json"]


def swarm(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "swarm_cli.main", *args], capture_output=True, text=True, timeout=600, cwd=ROOT)


def measured_out(doc: dict) -> dict:
    """The summary without the CPU seconds (a measurement of each run, not a result of the seeds)."""
    return {**doc, "methods": {m: {k: v for k, v in s.items() if k != "cpu_s_mean"} for m, s in doc["methods"].items()}}


def csv_rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return [{k: v for k, v in r.items() if k != "cpu_s"} for r in csv.DictReader(f)]


def test_ctrl_c_then_resume_gives_the_uninterrupted_result(tmp_path):
    whole = swarm(*COMPARE, "--out", str(tmp_path / "whole"))
    assert whole.returncode == 0, whole.stderr
    out = tmp_path / "cut"
    # Ctrl-C as from a terminal: SIGINT at its default even where this test runs as a background job (which ignores it)
    proc = subprocess.Popen([sys.executable, "-m", "swarm_cli.main", *COMPARE, "--out", str(out)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        log = out / "runs.jsonl"
        deadline = time.monotonic() + 300
        while not (log.exists() and len(log.read_text().splitlines()) >= 1 + 3):  # the options and three finished runs
            assert proc.poll() is None and time.monotonic() < deadline, "the comparison ended before it could be interrupted"
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130 and "swarm compare: interrupted" in err and "Traceback" not in err
    kept = len(log.read_text().splitlines()) - 1
    assert 3 <= kept < 12  # the finished runs survived, the rest did not run
    assert len(csv_rows(out / "runs.csv")) == kept

    resumed = swarm(*COMPARE, "--out", str(out), "--resume")
    assert resumed.returncode == 0, resumed.stderr
    assert len(log.read_text().splitlines()) == 1 + 12  # only the missing runs were added
    a, b = (json.loads(p.stdout.strip().splitlines()[-1]) for p in (whole, resumed))
    assert measured_out(a) == measured_out(b)
    assert csv_rows(tmp_path / "whole" / "runs.csv") == csv_rows(out / "runs.csv")


def test_resume_with_other_options_is_refused_and_keeps_the_log(tmp_path):
    first = swarm(*COMPARE[:7], "--trajectories", "1", "--configs", "1", "--methods", "ref57", "--out", str(tmp_path))
    assert first.returncode == 0, first.stderr
    before = (tmp_path / "runs.jsonl").read_text()
    again = swarm(*COMPARE[:7], "--trajectories", "1", "--configs", "1", "--methods", "ref57", "--seed", "5", "--out", str(tmp_path), "--resume")
    assert again.returncode == 2 and "--resume" in again.stderr and "seed = 0, not 5" in again.stderr
    assert (tmp_path / "runs.jsonl").read_text() == before


def _file_limit() -> None:
    resource.setrlimit(resource.RLIMIT_FSIZE, (FILE_LIMIT, FILE_LIMIT))  # a full disk as a user can make one: ulimit -f


FILE_LIMIT = 2500  # bytes: the study's CSV outgrows it after a few runs (writes then fail with EFBIG; Python ignores SIGXFSZ)


def test_a_study_whose_output_cannot_be_written_names_it_exits_5_and_leaves_no_temporary_file(tmp_path):
    out = tmp_path / "full"
    proc = subprocess.run([sys.executable, "-m", "swarm_cli.main", *COMPARE, "--workers", "1", "--out", str(out)], cwd=ROOT,
                          capture_output=True, text=True, timeout=600, preexec_fn=_file_limit)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 5, proc.stderr[-2000:]
    assert lines[-1].startswith("swarm compare: error: cannot write ") and str(out / "runs.") in lines[-1], lines[-1]
    assert "File too large" in lines[-1] and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert not list(out.glob("*.tmp")), sorted(p.name for p in out.iterdir())


def test_a_csv_that_cannot_be_written_is_named_and_its_temporary_file_removed(tmp_path):
    """``write_rows`` (every study's CSV) past the file size limit: ``OutputError`` naming the CSV, no ``.tmp`` left."""
    code = (f"from pathlib import Path; from inchworm.runner import write_rows; from runtime.errors import OutputError\n"
            f"try:\n    write_rows(Path({str(tmp_path / 'runs.csv')!r}), [{{'x': 'y' * 100}}] * 100)\n"
            f"except OutputError as e:\n    print(e)")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60, preexec_fn=_file_limit)
    assert proc.stdout.strip() == f"cannot write {tmp_path / 'runs.csv'}: File too large", proc.stdout + proc.stderr
    assert list(tmp_path.iterdir()) == []
