"""Timing helper shared by the bench scripts (imported as a sibling module: bench/ is on sys.path)."""
from __future__ import annotations

import os
import platform
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


def machine_facts(**versions) -> list[tuple[str, str]]:
    """CPU, cores, load, OS and Python of this machine, plus the given package versions, as (name, value)."""
    cpu = platform.processor() or "unknown"
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    facts = [("CPU", cpu), ("cores (os.cpu_count / usable)", f"{os.cpu_count()} / {len(os.sched_getaffinity(0))}"),
             ("load average (1/5/15 min)", "%.2f %.2f %.2f" % os.getloadavg()),
             ("OS", f"{platform.system()} {platform.release()}"), ("Python", platform.python_version())]
    return facts + [(name, str(version)) for name, version in versions.items()]
