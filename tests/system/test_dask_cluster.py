"""``swarm compare --scheduler`` on a real Dask cluster (a ``dask scheduler`` and two ``dask worker`` processes on
loopback, one of them killed mid-study) and ``--executor dask`` give the local pool's result: the same JSON and
CSV, the measured CPU seconds left out."""

from __future__ import annotations

import csv
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from runtime.wire.transport import free_tcp_port

ROOT = Path(__file__).resolve().parents[2]
DASK = Path(sys.executable).with_name("dask")
COMPARE = ["compare", "--robots", "6", "--trajectories", "4", "--configs", "2", "--methods", "inchworm,ref57", "--samples", "4", "--json"]


def swarm(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "swarm_cli.main", *args], capture_output=True, text=True, timeout=600, cwd=ROOT)


def result(proc: subprocess.CompletedProcess, out: Path) -> tuple[dict, list[dict]]:
    """The JSON without ``cpu_s_mean`` and the CSV rows without ``cpu_s`` (measurements, not results of the seeds)."""
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout.strip().splitlines()[-1])
    doc["methods"] = {m: {k: v for k, v in s.items() if k != "cpu_s_mean"} for m, s in doc["methods"].items()}
    with open(out / "runs.csv", newline="") as f:
        return doc, [{k: v for k, v in r.items() if k != "cpu_s"} for r in csv.DictReader(f)]


def start(*args: str) -> subprocess.Popen:
    return subprocess.Popen([str(DASK), *args], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def wait_for_port(port: int, proc: subprocess.Popen, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while True:
        assert proc.poll() is None and time.monotonic() < deadline, "dask scheduler did not start"
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.kill(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()


def test_a_real_cluster_losing_a_worker_gives_the_local_pools_result(tmp_path):
    local = result(swarm(*COMPARE, "--workers", "2", "--out", str(tmp_path / "local")), tmp_path / "local")
    port = free_tcp_port()  # (below the ephemeral range: no outgoing connection takes it meanwhile)
    address = f"tcp://127.0.0.1:{port}"
    procs = [start("scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard")]
    try:
        wait_for_port(port, procs[0])
        worker = ["worker", address, "--host", "127.0.0.1", "--nthreads", "1", "--no-nanny", "--no-dashboard"]
        procs += [start(*worker), start(*worker)]
        out = tmp_path / "cluster"
        study = subprocess.Popen([sys.executable, "-m", "swarm_cli.main", *COMPARE, "--scheduler", address, "--out", str(out)],
                                 cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        procs.append(study)
        log = out / "runs.jsonl"
        deadline = time.monotonic() + 300
        while not (log.exists() and len(log.read_text().splitlines()) >= 1 + 1):  # the options and one finished run
            assert study.poll() is None and time.monotonic() < deadline, study.stderr.read() if study.poll() is not None else "timeout"
            time.sleep(0.05)
        assert len(log.read_text().splitlines()) - 1 < 8, "the study ended before a worker could be lost"
        os.kill(procs[2].pid, signal.SIGKILL)  # a worker lost mid-study
        procs[2].wait()
        stdout, stderr = study.communicate(timeout=600)
        assert result(subprocess.CompletedProcess(study.args, study.returncode, stdout, stderr), out) == local
    finally:
        for proc in reversed(procs):
            stop(proc)


def test_a_local_dask_cluster_gives_the_local_pools_result(tmp_path):
    local = result(swarm(*COMPARE, "--workers", "1", "--out", str(tmp_path / "local")), tmp_path / "local")
    on_dask = result(swarm(*COMPARE, "--executor", "dask", "--workers", "2", "--out", str(tmp_path / "dask")), tmp_path / "dask")
    assert on_dask == local
