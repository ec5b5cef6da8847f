"""Timing helper shared by the bench scripts (imported as a sibling module: bench/ is on sys.path)."""
from __future__ import annotations

import time


def best_time(fn, repeat: int) -> float:
    """Best (minimum) wall time of `repeat` calls of fn after one warm-up call, in seconds."""
    fn()
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best
