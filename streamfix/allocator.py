"""Keep the memory a cleaning process frees, instead of handing it back to the system.

Why: glibc's ``malloc`` serves a request above its mmap threshold (128 KiB at first) with a
fresh ``mmap`` and unmaps it on ``free``, and it returns free memory at the top of its heap
once that exceeds the trim threshold. A window solve allocates and frees the same few
megabyte-sized arrays dozens of times (a 120 Hz take's window: 2,241 frames x 93 coordinates,
1.7 MB each), so each one came back as new pages that the kernel zeroes and maps on first
touch: thousands of page faults per solve, a visible part of its CPU time
(``benchmarks/bench_speed.py`` prints the faults of one clean beside the frames/s).
Raising both thresholds keeps those pages in the process: after the first solve the same
arrays reuse them, at the cost of a resident size that stays at its peak.

``streamfix`` applies this at start (:func:`streamfix.cli.main`), and so do the processes of
its own it may start: an archive worker (:func:`streamfix.archive.clean_file`) and ``serve
--solver-process``'s solver child (:mod:`streamfix.streaming.solver_process`). Where
the C library is not glibc, or the user set glibc's own ``MALLOC_MMAP_THRESHOLD_`` /
``MALLOC_TRIM_THRESHOLD_`` (theirs win), nothing changes.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

__all__ = ["MMAP_THRESHOLD_BYTES", "TRIM_THRESHOLD_BYTES", "keep_freed_memory"]

MMAP_THRESHOLD_BYTES = 32 << 20
"""Allocations up to this size (32 MiB) come from the heap and are reused after ``free``;
larger ones are still mapped and unmapped each time. A 20 s file window of a 120 Hz take
with 100 joints is 5.8 MB per array, well below."""

TRIM_THRESHOLD_BYTES = 256 << 20
"""Free memory kept at the top of the heap before any is returned to the system (256 MiB)."""

_M_TRIM_THRESHOLD = -1  # glibc's mallopt parameter numbers (malloc.h)
_M_MMAP_THRESHOLD = -3
_USER_SETTINGS = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "GLIBC_TUNABLES")

_applied: bool | None = None


def keep_freed_memory() -> bool:
    """Raise glibc's mmap and trim thresholds for this process (once; later calls return the
    first call's answer). Returns True when they were set, False where they could not be (not
    glibc) or the user's own settings stand."""
    global _applied
    if _applied is not None:
        return _applied
    _applied = False
    if not sys.platform.startswith("linux") or any(name in os.environ for name in _USER_SETTINGS):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # musl and others: no mallopt
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    _applied = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
    return _applied
