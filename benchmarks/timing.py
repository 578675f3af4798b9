"""Measuring: medians of repeated timings, and peak traced memory."""

from __future__ import annotations

import time
import tracemalloc
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class BenchRow:
    """One line of docs/benchmarks.md.

    name      : what was measured.
    median_s  : median wall time of one repetition, seconds.
    repeats   : how many repetitions the median is over.
    target    : the goal it is judged against (text), or "".
    result    : the headline figure (e.g. "41 Hz"), compared with the target.
    notes     : context (sizes, peak memory, the paper's figure).
    """

    name: str
    median_s: float
    repeats: int
    target: str
    result: str
    notes: str


def median_time(function: Callable[[], Any], repeats: int, warmup: int = 1) -> float:
    """Median wall time (s) of `function()` over `repeats` runs after `warmup` runs."""
    for _ in range(warmup):
        function()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    times.sort()
    return times[len(times) // 2]


def peak_memory_mb(function: Callable[[], Any]) -> float:
    """Peak memory (MB) allocated through Python and numpy while `function()` runs."""
    tracemalloc.start()
    try:
        function()
        return tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()
