"""Timing helper shared by the benchmark scripts (run as `python benchmarks/NAME.py`)."""

import time

import numpy as np


def timed(fn, calls: int, warmup: int = 3):
    """(median, p99) seconds per call of `fn()` (which must block until done)."""
    for _ in range(warmup):
        fn()
    times = np.empty(calls)
    for i in range(calls):
        t0 = time.perf_counter()
        fn()
        times[i] = time.perf_counter() - t0
    return float(np.median(times)), float(np.percentile(times, 99))
