"""The machine a benchmark ran on (CPU model, cores, Python), for docs/benchmarks.md, and the
timing rule every benchmark uses (:func:`best_time`)."""

from __future__ import annotations

import os
import platform
import time


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, {platform.system()}"


def best_time(fn, repeats: int) -> float:
    """The shortest of ``repeats`` wall-clock times of ``fn()`` (s): the least disturbed run on a
    shared machine."""
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best
