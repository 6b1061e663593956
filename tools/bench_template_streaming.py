#!/usr/bin/env python3
"""What streaming a template costs: scenes at the paper's scale run with their
templates read whole (the default budget) and streamed from their files
under smaller `--template-memory` budgets, alternating, side by side in one
sitting. Writes streaming.md and streaming.json (machine, date, command,
every run) into --out.

    build/venv/bin/python tools/bench_template_streaming.py                # blade3d and letters3d, 60 frames
    build/venv/bin/python tools/bench_template_streaming.py --scenes scenes/blade3d.json --frames 20 --out /tmp/s

The paper-scale templates must be recorded first (`make templates-paper`).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from bench_report import report_start, run_with_stats, write_report  # tools/, beside this script

ROOT = Path(__file__).resolve().parents[1]
FLOWCLIP_BIN = Path(os.environ.get("FLOWCLIP_BIN", ROOT / "build" / "flowclip"))


def run(scene: Path, frames: int, threads: int, budget: float | None, tmp: Path) -> dict:
    stats = tmp / "stats.json"
    cmd = [str(FLOWCLIP_BIN), "run", str(scene), "--scale", "paper", "--frames", str(frames), "--threads",
           str(threads), "--stats", str(stats), "--quiet"]
    if budget is not None:
        cmd += ["--template-memory", f"{budget:g}"]
    data = run_with_stats(cmd, stats, ROOT)
    frames_, summary = data["frames"], data["summary"]
    streamed = summary.get("templates_streamed", [])
    return {"scene": scene.stem, "budget_mb": budget, "frames": len(frames_),
            "ms_per_frame": sum(f["wall_ms"] for f in frames_) / len(frames_),
            "control_ms_per_frame": summary.get("control_ms_per_frame", 0.0),
            "template_bind_s": summary.get("template_bind_s", 0.0),
            "peak_rss_mb": summary["peak_rss_mb"],
            "streamed": len(streamed),
            "frames_read": sum(t["frames_read"] for t in streamed),
            "frames_reused": sum(t["frames_reused"] for t in streamed),
            "cache_peak_mb": sum(t["peak_mb"] for t in streamed),
            "read_s": sum(t["read_s"] for t in streamed)}


def markdown(report: dict) -> str:
    m = report["machine"]
    lines = [
        "# Streaming templates: what it costs", "",
        f"- date: {report['date']}",
        f"- command: `{report['command']}`",
        f"- machine: {m['cpu']}, {m['cores']} cores, Linux {m['kernel']}; niceness {m['niceness']}",
        f"- load average (1, 5, 15 min): {m['loadavg_at_start']} at the start, {report['loadavg_at_end']} at the end",
        f"- {report['threads']} OpenMP threads; {report['frames']} frames per run at `--scale paper`, "
        f"{report['repeat']} alternating round(s), the median of each setting", "",
        "*whole*: the default budget, every template read and built at load; a budget in MB: "
        "`--template-memory`, the templates that do not fit it streamed. *bind s*: loading the templates "
        "before the first frame; *read s*: reading, decoding and building streamed frames during the run "
        "(part of the control ms).", "",
        "| scene | templates | ms / frame | control ms / frame | bind s | peak RSS MB | streamed | frames read "
        "(reused) | cache peak MB | read s |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in report["runs"]:
        budget = "whole" if r["budget_mb"] is None else f"{r['budget_mb']:g} MB"
        lines.append(f"| {r['scene']} | {budget} | {r['ms_per_frame']:.0f} | {r['control_ms_per_frame']:.1f} "
                     f"| {r['template_bind_s']:.2f} | {r['peak_rss_mb']:.0f} | {r['streamed']} "
                     f"| {r['frames_read']} ({r['frames_reused']}) | {r['cache_peak_mb']:.1f} | {r['read_s']:.2f} |")
    lines.append("")
    return "\n".join(lines)


def median_run(runs: list[dict]) -> dict:
    runs = sorted(runs, key=lambda r: r["ms_per_frame"])
    return runs[len(runs) // 2]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="scenes/blade3d.json,scenes/letters3d.json",
                    help="scenes, comma-separated (default blade3d and letters3d)")
    ap.add_argument("--budgets", default="64,16", help="--template-memory budgets in MB, comma-separated")
    ap.add_argument("--frames", type=int, default=60, help="frames per run (default 60)")
    ap.add_argument("--repeat", type=int, default=1, help="alternating rounds (default 1)")
    ap.add_argument("--threads", type=int, default=2, help="OpenMP threads (default 2)")
    ap.add_argument("--out", default="bench/template-streaming", help="report directory")
    a = ap.parse_args()
    if not FLOWCLIP_BIN.exists():
        raise SystemExit(f"{FLOWCLIP_BIN} is missing: build first (make build) or set FLOWCLIP_BIN")
    budgets: list[float | None] = [None] + [float(b) for b in a.budgets.split(",") if b]
    report = report_start("tools/bench_template_streaming.py", sys.argv[1:])
    report.update({"threads": a.threads, "frames": a.frames, "repeat": a.repeat})
    report["runs"] = []
    with tempfile.TemporaryDirectory(prefix="flowclip-bench-streaming-") as tmp:
        for scene in a.scenes.split(","):
            rounds = [[run(ROOT / scene, a.frames, a.threads, b, Path(tmp)) for b in budgets]
                      for _ in range(a.repeat)]
            report["runs"] += [median_run([r[k] for r in rounds]) for k in range(len(budgets))]
    write_report(Path(a.out), "streaming", report, markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
