"""Keep freed memory for reuse: the planner's batch allocates and frees arrays of 0.1-1 MB thousands of times a selection.

glibc returns the free top of its heap to the system once it exceeds the trim threshold (dynamic, about twice the
largest block freed) and serves larger blocks by ``mmap``; either way the next allocation of such an array starts
on fresh pages, each a page fault on its first touch. One n_r = 10 selection with the joint localizer took ~74,000
minor page faults, ~15 % of its time (docs/benchmarks.md). ``retain_freed_memory`` fixes both thresholds
(``RETAIN_BYTES`` of free heap kept, blocks up to ``HEAP_BLOCK_BYTES`` from the heap): the process keeps at most
that much freed memory and stops faulting. Results do not change: only where numpy's buffers come from.

A no-op where the C library is not glibc (``mallopt`` missing) or on other systems.
"""

from __future__ import annotations

import ctypes
import functools
import sys

M_TRIM_THRESHOLD = -1  # glibc's mallopt parameters (malloc.h)
M_MMAP_THRESHOLD = -3
RETAIN_BYTES = 64 << 20  # free memory at the top of the heap kept for reuse (bytes)
HEAP_BLOCK_BYTES = 32 << 20  # allocations up to this size come from the heap, larger ones from mmap (bytes): the largest
# threshold glibc allows, which its dynamic threshold reaches on its own; fixed, it stays there from the start


@functools.cache
def retain_freed_memory() -> bool:
    """Set glibc's trim and mmap thresholds once per process; True where they were set."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(M_TRIM_THRESHOLD, RETAIN_BYTES)) and bool(mallopt(M_MMAP_THRESHOLD, HEAP_BLOCK_BYTES))
