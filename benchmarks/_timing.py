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


def paired(fn_a, fn_b, calls: int, warmup: int = 1):
    """(median_a, p99_a, median_b, p99_b) seconds per call of `fn_a()` and `fn_b()` timed in
    alternation (a, b, a, b, …), so a change of the machine's load falls on both alike: their
    ratio is the evidence on a noisy machine."""
    for _ in range(warmup):
        fn_a()
        fn_b()
    times = np.empty((calls, 2))
    for i in range(calls):
        for j, fn in enumerate((fn_a, fn_b)):
            t0 = time.perf_counter()
            fn()
            times[i, j] = time.perf_counter() - t0
    med = np.median(times, axis=0)
    p99 = np.percentile(times, 99, axis=0)
    return float(med[0]), float(p99[0]), float(med[1]), float(p99[1])
