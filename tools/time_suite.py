#!/usr/bin/env python3
"""The test suite's wall time, part by part, over several runs in a row: `make test`'s parts
(`make test-parts`) run one after the other after the warm build (`make build templates web`),
each timed, and any run can be put under load (N busy processes at normal priority, as
`stress --cpu N` would). Writes a report (markdown + JSON: machine, date, command, figures)
with each run's parts, totals and outcome.

Usage: tools/time_suite.py [--runs 3] [--loaded 3] [--load-procs 2] [--out bench/suite]
(`make bench-suite`). Not part of `make test`: it runs it.
"""

from __future__ import annotations

import argparse
import datetime
import json
import multiprocessing
import os
import subprocess
import sys
import time
from pathlib import Path

from bench_report import loadavg, machine  # tools/, beside this script

ROOT = Path(__file__).resolve().parent.parent


def spin() -> None:
    while True:
        pass


def make(target: str, log) -> tuple[float, int]:
    """Runs `make TARGET` from the root, its output into log; (wall seconds, exit status)."""
    start = time.monotonic()
    log.write(f"\n===== make {target}\n")
    log.flush()
    status = subprocess.run(["make", "--no-print-directory", target], cwd=ROOT, stdout=log,
                            stderr=subprocess.STDOUT).returncode
    return time.monotonic() - start, status


def run_once(index: int, loaded: bool, procs: int, parts: list[str], log, report: dict, out: Path) -> dict:
    """One run, appended to report["runs"] at its start and the report rewritten after every part, so
    that a run stopped part-way keeps what it measured (marked incomplete)."""
    spinners = [multiprocessing.Process(target=spin, daemon=True) for _ in range(procs if loaded else 0)]
    for p in spinners:
        p.start()
    try:
        result = {"run": index, "loaded": loaded, "load_procs": len(spinners), "loadavg_at_start": loadavg(),
                  "parts": [], "prepare_s": 0.0, "tests_s": 0.0, "passed": False, "complete": False}
        report["runs"].append(result)
        prepare_s, status = 0.0, 0
        # The builds the parts need, so that a part's time is its tests only.
        builds = ["build", "templates", "web"] + ["fuzz-build"] * ("test-fuzz" in parts) + ["asan-build"] * ("test-asan" in parts)
        for target in builds:
            seconds, st = make(target, log)
            prepare_s, status = prepare_s + seconds, status or st
        result["prepare_s"] = round(prepare_s, 1)
        for part in parts:
            seconds, st = make(part, log)
            result["parts"].append({"part": part, "seconds": round(seconds, 1), "status": st})
            result["tests_s"] = round(sum(p["seconds"] for p in result["parts"]), 1)
            write_report(out, report)
            print(f"run {index}{' (loaded)' if loaded else ''}: {part} {seconds:.0f} s, "
                  f"{'ok' if st == 0 else f'FAILED ({st})'}", flush=True)
        result["tests_s"] = round(sum(p["seconds"] for p in result["parts"]), 1)
        result["passed"] = status == 0 and all(p["status"] == 0 for p in result["parts"])
        result["complete"] = True
        result["loadavg_at_end"] = loadavg()
        return result
    finally:
        for p in spinners:
            p.terminate()
            p.join()


def verdict(runs: list[dict]) -> str:
    if any(outcome(r) == "FAIL" for r in runs):
        return "FAILED"
    return "all green" if all(r.get("complete", True) for r in runs) else "green so far (a run was stopped)"


def outcome(run: dict) -> str:
    if not run.get("complete", True):
        return "incomplete (stopped)" if all(p["status"] == 0 for p in run["parts"]) else "FAIL"
    return "pass" if run["passed"] else "FAIL"


def write_report(out: Path, report: dict) -> None:
    runs = report["runs"]
    parts = [p["part"] for p in runs[0]["parts"]] if runs else []
    lines = [f"# The test suite's wall time: {len(runs)} run{'s in a row' if len(runs) != 1 else ''}", "",
             f"- date: {report['date']}", f"- machine: {report['machine']['cpu']}, {report['machine']['cores']} cores",
             f"- command: `{report['command']}`",
             f"- verdict: **{verdict(runs)}**", "",
             "Seconds of wall time per part of `make test`, after the builds they need (the column prepare:",
             "`make build templates web`, and the fuzz and sanitizer builds for their parts). A loaded run",
             "shares the machine with busy processes at normal priority.", "",
             "| run | load | loadavg at start | prepare | " + " | ".join(parts) + " | tests total | outcome |",
             "|---|---|---|---|" + "---|" * len(parts) + "---|---|"]
    for r in runs:
        cells = [f"{p['seconds']:.0f}" + ("" if p["status"] == 0 else " (failed)") for p in r["parts"]]
        cells += ["not run"] * (len(parts) - len(cells))
        load = f"{r['load_procs']} busy processes" if r["loaded"] else "quiet"
        lines.append(f"| {r['run']} | {load} | {r['loadavg_at_start']} | {r['prepare_s']:.0f} | " + " | ".join(cells)
                     + f" | {r['tests_s']:.0f} ({r['tests_s'] / 60:.1f} min) | {outcome(r)} |")
    out.mkdir(parents=True, exist_ok=True)
    for name, text in (("suite.md", "\n".join(lines) + "\n"), ("suite.json", json.dumps(report, indent=1) + "\n")):
        tmp = out / f".{name}.tmp"
        tmp.write_text(text)
        os.replace(tmp, out / name)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3, help="runs of the suite in a row (default 3)")
    ap.add_argument("--loaded", type=int, nargs="*", default=[3], help="which runs (1-based) run under load (default: 3)")
    ap.add_argument("--load-procs", type=int, default=os.cpu_count() or 2, help="busy processes during a loaded run")
    ap.add_argument("--out", default="bench/suite", help="report folder (default bench/suite)")
    ap.add_argument("--log", default="build/time_suite.log", help="the runs' output (default build/time_suite.log)")
    ap.add_argument("--parts", nargs="*", help="only these parts of `make test-parts` (default: all)")
    args = ap.parse_args()
    parts = subprocess.run(["make", "-s", "test-parts"], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.split()
    if args.parts:
        unknown = sorted(set(args.parts) - set(parts))
        if unknown:
            ap.error(f"not parts of make test: {', '.join(unknown)} (they are: {' '.join(parts)})")
        parts = [p for p in parts if p in args.parts]
    report = {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
              "machine": machine(), "command": " ".join(["tools/time_suite.py"] + sys.argv[1:]), "parts": parts,
              "runs": []}
    out = ROOT / args.out
    with open(ROOT / args.log, "w") as log:
        for i in range(1, args.runs + 1):
            run_once(i, i in args.loaded, args.load_procs, parts, log, report, out)
            write_report(out, report)
    print(f"report: {out / 'suite.md'}")
    return 0 if all(r["passed"] for r in report["runs"]) else 1


if __name__ == "__main__":
    sys.exit(main())
