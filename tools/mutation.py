"""Mutation testing of the paper's maths: ``python -m tools.mutation [GLOB ...] [--max-children N] [--json]``.

Runs mutmut (``pip install -e '.[dev,mutation]'``) with the ``[tool.mutmut]`` configuration of
pyproject.toml: it mutates coordinator/localization/, coordinator/selection/, coordinator/plan.py
and runtime/models/metrics.py one small change at a time (a ``+`` for a ``-``, 0.5 for 1.5, a dropped
statement ...) and runs the fast maths tests that cover each mutated function; a mutant is
killed when a test fails. It prints the score (killed / checked) per module and in total.

GLOBs restrict the run to mutant names (``coordinator.plan.*``, ``runtime.models.metrics.*``); without
them every mutant of the configured modules runs (long: tens of minutes on 2 cores). mutmut keeps
its results in ``mutants/`` and re-runs only what changed. Not part of CI's default run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from collections import Counter
from fnmatch import fnmatch
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
KILLED = {1, 3, 36, 24, -24, 152, 255}  # test failure, pytest error, timeout (mutmut's own exit-code mapping)
SURVIVED = {0}
NO_TESTS = {5, 33}


def module_scores(globs: list[str]) -> dict[str, Counter]:
    """Per source file: counts of killed / survived / no-tests / other mutants matching ``globs``, from mutants/*.meta."""
    out: dict[str, Counter] = {}
    for meta in sorted((ROOT / "mutants").rglob("*.py.meta")):
        codes = json.loads(meta.read_text()).get("exit_code_by_key", {})
        counts: Counter = Counter()
        for name, code in codes.items():
            if globs and not any(fnmatch(name, g) for g in globs):
                continue
            if code is None:
                counts["not checked"] += 1
            elif code in KILLED:
                counts["killed"] += 1
            elif code in SURVIVED:
                counts["survived"] += 1
            elif code in NO_TESTS:
                counts["no tests"] += 1
            else:
                counts["other"] += 1
        if counts:
            out[str(meta.relative_to(ROOT / "mutants"))[: -len(".meta")]] = counts
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.mutation", description=__doc__.splitlines()[0])
    parser.add_argument("globs", nargs="*", help="mutant-name globs, e.g. 'runtime.models.metrics.*' (default: all)")
    parser.add_argument("--max-children", type=int, default=1, help="parallel mutant runs (default 1: a shared machine)")
    parser.add_argument("--report-only", action="store_true", help="print the scores of the last run without running")
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    args = parser.parse_args(argv)
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    if not args.report_only:
        run = subprocess.run([sys.executable, "-m", "mutmut", "run", f"--max-children={args.max_children}", *args.globs],
                             cwd=ROOT, env=env)
        if run.returncode != 0:
            print(f"mutmut run failed with exit status {run.returncode}", file=sys.stderr)
            return run.returncode
    scores = module_scores(args.globs)
    if not scores:
        print("no mutation results in mutants/: run without --report-only first", file=sys.stderr)
        return 2
    total: Counter = Counter()
    print(f"{'module':55s} {'killed':>7s} {'survived':>8s} {'no tests':>8s} {'score':>7s}")
    for path, c in scores.items():
        total.update(c)
        checked = c["killed"] + c["survived"] + c["no tests"]
        if not checked:
            continue  # not run yet (or filtered out by the GLOBs of the last run)
        print(f"{path:55s} {c['killed']:7d} {c['survived']:8d} {c['no tests']:8d} {100 * c['killed'] / max(checked, 1):6.1f}%")
    checked = total["killed"] + total["survived"] + total["no tests"]
    score = total["killed"] / max(checked, 1)
    print(f"{'total':55s} {total['killed']:7d} {total['survived']:8d} {total['no tests']:8d} {100 * score:6.1f}%")
    print("survivors: mutmut results; one in full: mutmut show NAME")
    if args.json:
        print(json.dumps({"killed": total["killed"], "survived": total["survived"], "no_tests": total["no tests"],
                          "not_checked": total["not checked"], "score": score,
                          "modules": {p: dict(c) for p, c in scores.items()}}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
