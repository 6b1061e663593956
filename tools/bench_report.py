"""What the benchmarks' reports say about the machine they ran on (tools/bench_cache.py,
tools/soak.py): the CPU, its cores, the kernel, Python, the load average and the niceness, so
that a figure is read against the machine and how busy it was."""

from __future__ import annotations

import datetime
import json
import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Callable


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


def report_start(tool: str, argv: list[str]) -> dict:
    """The fields a report opens with: the date (UTC), the machine, the command that ran."""
    return {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "machine": machine(), "command": shlex.join([tool] + list(argv))}


def write_report(out: Path, name: str, report: dict, markdown: Callable[[dict], str]) -> None:
    """Closes the report with the load average at its end and writes NAME.json and NAME.md into OUT."""
    report["loadavg_at_end"] = loadavg()
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps(report, indent=1) + "\n")
    (out / f"{name}.md").write_text(markdown(report))
    print(f"bench {name}: {out / f'{name}.md'}, {out / f'{name}.json'}", file=sys.stderr, flush=True)


def run_with_stats(cmd: list[str], stats: Path, cwd: Path) -> dict:
    """Runs a `flowclip run ... --stats STATS` command (printed first; its stderr passes through)
    and returns the stats file's JSON; a failed run ends the benchmark."""
    print("$ " + shlex.join(cmd), file=sys.stderr, flush=True)
    proc = subprocess.run(cmd, cwd=cwd, stdout=subprocess.DEVNULL, stderr=sys.stderr)
    if proc.returncode != 0:
        raise SystemExit(f"flowclip run exited with {proc.returncode}")
    return json.loads(stats.read_text())
