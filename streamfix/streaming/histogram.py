"""Latency histograms of the streaming engine (live path and window solves), as its metrics report them."""
from __future__ import annotations

import bisect
from collections import deque

import numpy as np

__all__ = ["Histogram"]


class Histogram:
    """Fixed-bucket histogram of durations (s) plus a window of recent samples."""

    BOUNDS = (0.0001, 0.0002, 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)

    def __init__(self, recent: int = 2048) -> None:
        self.counts = np.zeros(len(self.BOUNDS) + 1, dtype=np.int64)
        self.total = 0.0
        self.n = 0
        self.recent: deque[float] = deque(maxlen=recent)

    def observe(self, seconds: float) -> None:
        self.counts[bisect.bisect_left(self.BOUNDS, seconds)] += 1  # np.searchsorted's bucket
        self.total += seconds
        self.n += 1
        self.recent.append(seconds)

    def snapshot(self) -> dict:
        rec = np.asarray(self.recent) if self.recent else np.zeros(0)
        return {
            "bounds_s": list(self.BOUNDS),  # upper bounds; last count is +Inf
            "counts": self.counts.tolist(),  # per bucket, not cumulative
            "sum_s": self.total,
            "count": self.n,
            "p50_s": float(np.percentile(rec, 50)) if rec.size else 0.0,
            "p99_s": float(np.percentile(rec, 99)) if rec.size else 0.0,
            "max_s": float(rec.max()) if rec.size else 0.0,
        }
