"""Medians and repeated timed runs: every bench figure is a median over repetitions after warm-up runs."""

from __future__ import annotations

import statistics
import time


def median(values):
    return float(statistics.median(values)) if values else float("nan")


def timed(fn, reps, warmup):
    """Run fn() warmup + reps times; the median wall seconds of the timed runs, every wall time, the last result."""
    out = None
    for _ in range(warmup):
        out = fn()
    walls = []
    for _ in range(max(reps, 1)):
        t0 = time.perf_counter()
        out = fn()
        walls.append(time.perf_counter() - t0)
    return median(walls), walls, out
