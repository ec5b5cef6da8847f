"""Helpers shared by the bench scripts — timing, machine facts, Markdown tables (imported as a sibling
module: bench/ is on sys.path)."""
from __future__ import annotations

import os
import platform
import time

from fluxcal.pipeline import usable_cpus


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
    facts = [("CPU", cpu), ("cores (os.cpu_count / usable)", f"{os.cpu_count()} / {usable_cpus()}"),
             ("load average (1/5/15 min)", "%.2f %.2f %.2f" % os.getloadavg()),
             ("OS", f"{platform.system()} {platform.release()}"), ("Python", platform.python_version())]
    return facts + [(name, str(version)) for name, version in versions.items()]


def table(header: list[str], rows: list[list[str]], out=print):
    """A Markdown table: the first column left-aligned, the others right-aligned, padded to fit."""
    widths = [max(len(str(c)) for c in col) for col in zip(header, *rows)]
    out("| " + " | ".join(str(h).ljust(w) for h, w in zip(header, widths)) + " |")
    out("|" + "|".join("-" * (w + 1) + ":" if i else "-" * (w + 2) for i, w in enumerate(widths)) + "|")
    for r in rows:
        out("| " + " | ".join(str(c).ljust(w) if i == 0 else str(c).rjust(w)
                              for i, (c, w) in enumerate(zip(r, widths))) + " |")
