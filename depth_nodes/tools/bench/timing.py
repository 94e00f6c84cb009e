"""Timing shared by the benchmarks: interleaved medians."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np


def median_ms(fns: dict[str, Callable[[], Any]], repeats: int,
              settle: float = 0.0) -> dict[str, float]:
    """Median wall time in ms of each function, over ``repeats`` interleaved rounds.

    Every round calls each function once, so a slow spell of the machine affects all of
    them alike and their ratios stay meaningful. One untimed warm-up round comes first.
    ``settle`` seconds of sleep precede each timed call: OpenCV's worker threads keep
    spinning for a moment after a call returns and would otherwise slow down whatever
    runs next on this 2-core machine.
    """
    for fn in fns.values():
        fn()
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            if settle:
                time.sleep(settle)
            start = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - start)
    return {name: float(np.median(t) * 1e3) for name, t in times.items()}
