"""What the benchmarks' reports say about the machine they ran on (tools/bench_cache.py,
tools/soak.py): the CPU, its cores, the kernel, Python, the load average and the niceness, so
that a figure is read against the machine and how busy it was."""

from __future__ import annotations

import os
import platform
from pathlib import Path


def loadavg() -> str:
    """The 1, 5 and 15 minute load averages ("" where /proc has none)."""
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return ""


def machine() -> dict:
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "kernel": platform.release(),
            "python": platform.python_version(), "loadavg_at_start": loadavg(), "niceness": os.nice(0)}
