#!/usr/bin/env python3
"""How the solver's cost per particle-step and its memory per particle grow
with the particle count: the 3D dam break (scenes/bench/dambreak3d_r0125.json,
59k particles as SPlisHSPlasH's) at finer radii up to about a million
particles, each run its own `flowclip run --particle-radius R` over the same
simulated time, side by side in one sitting. Writes scaling.md and
scaling.json (machine, date, command, every run) into --out.

    build/venv/bin/python tools/bench_scaling.py                 # 59k .. 1M, 0.1 s each, 2 threads
    build/venv/bin/python tools/bench_scaling.py --seconds 0.05 --counts 59k,250k --out /tmp/scaling

The first frame is left out of the per-step figure (it holds the set-up:
sampling the walls, the first neighbour search); peak memory is the run's
peak RSS divided by its liquid particles.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

from bench_report import report_start, run_with_stats, write_report  # tools/, beside this script

ROOT = Path(__file__).resolve().parents[1]
FLOWCLIP_BIN = Path(os.environ.get("FLOWCLIP_BIN", ROOT / "build" / "flowclip"))
SCENE = ROOT / "scenes" / "bench" / "dambreak3d_r0125.json"


def count_arg(text: str) -> int:
    t = text.strip().lower()
    scale = 1_000_000 if t.endswith("m") else 1_000 if t.endswith("k") else 1
    return int(float(t.rstrip("mk")) * scale)


def radius_for(count: int) -> float:
    """The radius at which the scene's cubic block holds n³ ≈ `count`
    particles, n per edge (its lattice spacing is the diameter)."""
    block = json.loads(SCENE.read_text())["fluid_blocks"][0]
    edge = min(hi - lo for lo, hi in zip(block["min"], block["max"]))
    n = round(count ** (1 / 3))
    return edge / (2 * n)


def run(radius: float, seconds: float, threads: int, tmp: Path) -> dict:
    stats = tmp / f"r{radius:.6f}.json"
    cmd = [str(FLOWCLIP_BIN), "run", str(SCENE), "--particle-radius", f"{radius:.6g}", "--seconds", str(seconds),
           "--threads", str(threads), "--stats", str(stats)]
    data = run_with_stats(cmd, stats, ROOT)
    frames, summary = data["frames"], data["summary"]
    steady = frames[1:] or frames
    wall_ms = sum(f["wall_ms"] for f in steady)
    particle_steps = sum(f["particles"] * f["substeps"] for f in steady)
    liquid = summary["liquid_particles"]
    return {"particle_radius": radius, "liquid_particles": liquid,
            "boundary_particles": summary["boundary_particles"], "frames": len(frames),
            "substeps_per_frame": sum(f["substeps"] for f in steady) / len(steady),
            "solver_iterations_per_substep": sum(f.get("density_iterations", 0) + f.get("divergence_iterations", 0)
                                                 for f in steady) / max(1, sum(f["substeps"] for f in steady)),
            "us_per_particle_step": wall_ms * 1000 / particle_steps,
            "ms_per_frame": wall_ms / len(steady),
            "wall_s_per_simulated_s": summary["wall_s_per_simulated_s"],
            "peak_rss_mb": summary["peak_rss_mb"],
            "bytes_per_liquid_particle": summary["peak_rss_mb"] * 1e6 / liquid,
            "memory_bytes": summary["memory_bytes"],
            "unconverged_frames": summary["unconverged_frames"]}


# The run summary's memory parts (`memory_bytes`), in the order of the breakdown table.
PARTS = [("liquid_particles", "liquid arrays"), ("neighbour_lists", "neighbour lists"),
         ("pair_terms", "pair terms"), ("neighbour_grids", "neighbour grids"), ("boundary_sums", "boundary sums"),
         ("boundary_samples", "wall samples"), ("boundary_model", "boundary model")]


def markdown(report: dict) -> str:
    m = report["machine"]
    base = report["runs"][0]["us_per_particle_step"]
    lines = [
        "# Solver scaling: the 3D dam break from 59k to a million particles", "",
        f"- date: {report['date']}",
        f"- command: `{report['command']}`",
        f"- machine: {m['cpu']}, {m['cores']} cores, Linux {m['kernel']}; niceness {m['niceness']}",
        f"- load average (1, 5, 15 min): {m['loadavg_at_start']} at the start, {report['loadavg_at_end']} at the end",
        f"- {report['threads']} OpenMP threads; {report['seconds']} simulated s per run "
        "(the first frame, with the set-up, left out of the per-step figures); every size run "
        f"{report.get('repeat', 1)} times in rounds, each row its fastest run (all runs: the last column)", "",
        "| liquid particles | radius, mm | substeps / frame | solver iterations / substep | µs per particle-step "
        "| against the smallest | ms per frame | peak RSS MB | bytes per liquid particle | µs per particle-step, every run |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in report["runs"]:
        lines.append(f"| {r['liquid_particles']:,} | {1000 * r['particle_radius']:.3f} | {r['substeps_per_frame']:.1f} "
                     f"| {r['solver_iterations_per_substep']:.1f} | {r['us_per_particle_step']:.3f} "
                     f"| {r['us_per_particle_step'] / base:.2f} | {r['ms_per_frame']:.0f} | {r['peak_rss_mb']:.0f} "
                     f"| {r['bytes_per_liquid_particle']:.0f} "
                     f"| {', '.join(f'{u:.3f}' for u in r.get('us_per_particle_step_runs', [r['us_per_particle_step']]))} |")
    lines += ["", "The µs per particle-step include the solver's iterations, which change with the resolution "
              "(the step shrinks with the radius, so each substep starts closer to the solution): the column "
              "before them gives how many there were. Bytes per liquid particle hold the tank's wall samples "
              "too (as many as the liquid's at a million) and the process's own few tens of MB.", "",
              "## Where the memory is", "",
              "Bytes per liquid particle of each part the simulation's containers hold at the run's end "
              "(`flowclip run`'s `memory_bytes`: capacities), what they add up to, and the rest of the peak RSS: "
              "the pressure solver's and the effects' per-particle arrays, scratch released before the end, "
              "the libraries and the process.", "",
              "| liquid particles | " + " | ".join(name for _, name in PARTS) + " | counted | rest of peak RSS |",
              "|---:|" + "---:|" * (len(PARTS) + 2)]
    for r in report["runs"]:
        mem, n = r["memory_bytes"], r["liquid_particles"]
        rest = r["peak_rss_mb"] * 1e6 - mem["counted"]
        lines.append(f"| {n:,} | " + " | ".join(f"{mem[key] / n:.0f}" for key, _ in PARTS)
                     + f" | {mem['counted'] / n:.0f} | {rest / n:.0f} |")
    lines.append("")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--counts", default="59k,118k,250k,500k,1m",
                    help="liquid particle counts, comma-separated (default 59k,118k,250k,500k,1m)")
    ap.add_argument("--seconds", type=float, default=0.1, help="simulated seconds per run (default 0.1)")
    ap.add_argument("--threads", type=int, default=2, help="OpenMP threads (default 2)")
    ap.add_argument("--out", default="bench/scaling", help="report directory (scaling.md, scaling.json)")
    ap.add_argument("--repeat", type=int, default=3,
                    help="runs of every size, in rounds; each size's fastest is reported (default 3)")
    a = ap.parse_args()
    if not FLOWCLIP_BIN.exists():
        raise SystemExit(f"{FLOWCLIP_BIN} is missing: build first (make build) or set FLOWCLIP_BIN")
    counts = sorted(count_arg(c) for c in a.counts.split(","))
    report = report_start("tools/bench_scaling.py", sys.argv[1:])
    report.update({"threads": a.threads, "seconds": a.seconds, "scene": str(SCENE.relative_to(ROOT))})
    report["repeat"] = a.repeat
    with tempfile.TemporaryDirectory(prefix="flowclip-bench-scaling-") as tmp:
        # Every size once per round, so that the host's drift between runs reaches all of them;
        # each size keeps its fastest run, and the report lists every run's figure.
        rounds = [[run(radius_for(c), a.seconds, a.threads, Path(tmp)) for c in counts] for _ in range(a.repeat)]
    report["runs"] = []
    for k in range(len(counts)):
        tries = [r[k] for r in rounds]
        best = dict(min(tries, key=lambda r: r["us_per_particle_step"]))
        best["us_per_particle_step_runs"] = [r["us_per_particle_step"] for r in tries]
        report["runs"].append(best)
    write_report(Path(a.out), "scaling", report, markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
