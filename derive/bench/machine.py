"""The machine a benchmark ran on (CPU model, cores, Python), for docs/benchmarks.md, and the
timing rule every benchmark uses (:func:`best_time`)."""

from __future__ import annotations

import os
import platform
import shutil
import subprocess
import time


def machine() -> str:
    """CPU model (with its family and model numbers where /proc/cpuinfo has them: AMD EPYC
    machines of the same name differ, Zen 1 to Zen 4), cores, what gcc's -march=native means on
    it, Python and the system."""
    cpu = platform.processor() or platform.machine()
    fields = {}
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                key, _, value = line.partition(":")
                key = key.strip()
                if key in ("model name", "cpu family", "model") and key not in fields:
                    fields[key] = value.strip()
                if not line.strip() and fields:
                    break
    except OSError:
        pass
    if "model name" in fields:
        cpu = fields["model name"]
        if "cpu family" in fields and "model" in fields:
            cpu += f" (family {fields['cpu family']}, model {fields['model']})"
    arch = native_arch()
    return (f"{cpu}, {os.cpu_count()} cores{f', -march=native = {arch}' if arch else ''}, "
            f"Python {platform.python_version()}, {platform.system()}")


def native_arch() -> str | None:
    """What gcc's -march=native resolves to here (e.g. znver1, znver3, skylake-avx512), or None
    without gcc."""
    gcc = shutil.which("gcc")
    if gcc is None:
        return None
    try:
        out = subprocess.run([gcc, "-march=native", "-Q", "--help=target"], capture_output=True,
                             text=True, timeout=60).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[0] == "-march=":
            return parts[1]
    return None


def best_time(fn, repeats: int) -> float:
    """The shortest of ``repeats`` wall-clock times of ``fn()`` (s): the least disturbed run on a
    shared machine."""
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best
