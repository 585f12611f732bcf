"""The ``swarm`` command line: the top layer, built on ``runtime``, ``robot_agent`` and ``coordinator``.

The commands parallelise over processes (one per core), so each process keeps its BLAS
to one thread: several BLAS threads per process only oversubscribe the cores and make
the small batched solves of the Monte Carlo planner erratic. Set before numpy loads.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
