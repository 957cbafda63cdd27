"""Keep the learner's freed memory mapped, so large per-batch tensors stop page-faulting.

Why: glibc serves every allocation above its mmap threshold (adaptive, capped at 32 MB) with
fresh pages from the kernel and unmaps them on free, and trims the top of the heap above its trim
threshold. The update allocates and frees the same large activation tensors hundreds of times
(every line-search trial, gradient and Fisher product): at N = 200,000 one (N, 64) float32
activation is 51 MB, and each trial paid ~25,000 minor page faults and each surrogate gradient
~100,000 (`python results/update-cost/update_growth.py`, BENCHMARKS.md section 4). That made the update
grow faster than N. Raising both thresholds keeps those pages in the heap for reuse.

Results are unchanged: where a buffer lives does not change what is computed into it (torch
aligns every CPU allocation to 64 bytes either way), which tests/algorithm/test_allocator.py checks.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
"""mallopt(3) parameter numbers (glibc malloc.h)."""

DEFAULT_THRESHOLD_BYTES = 1 << 30
"""Allocations up to 1 GiB come from the heap, and up to 1 GiB of free heap top is kept."""


def keep_freed_memory(threshold_bytes: int = DEFAULT_THRESHOLD_BYTES) -> bool:
    """Raise glibc's mmap and trim thresholds for this process; False where that is not possible
    (not Linux, another C library), in which case nothing changes."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # musl and others have no mallopt
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    mmap_set = bool(mallopt(M_MMAP_THRESHOLD, threshold_bytes))
    return bool(mallopt(M_TRIM_THRESHOLD, threshold_bytes)) and mmap_set
