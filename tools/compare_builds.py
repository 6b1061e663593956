#!/usr/bin/env python3
"""Times one scene with two flowclip executables, alternating runs so that a
change in the machine's load hits both alike, and prints µs per
particle-step (median of the repeats) side by side.

    build/venv/bin/python tools/compare_builds.py --old OLD/flowclip --new build/flowclip \\
        scenes/dambreak2d.json --frames 60 --repeat 5

It is how "a plain dam break runs no slower than before the effects work"
is measured (docs/benchmarks/solver.md): OLD is a build of the commit
before the change. Both runs must do the same work (same substeps and
solver iterations); the script says so when they do not.

For a scene with template instances it also compares control's time per
frame with an active instance and its share of the simulation's time (as
`flowclip bench control` reports them).
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile


def run(binary, scene, frames, threads, radius):
    with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as f:
        stats = f.name
    cmd = [binary, "run", scene, "--frames", str(frames), "--stats", stats]
    if threads:
        cmd += ["--threads", str(threads)]
    if radius:
        cmd += ["--particle-radius", str(radius)]
    try:
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        with open(stats) as fh:
            s = json.load(fh)
    finally:
        os.unlink(stats)
    frames_ = s["frames"]
    active = [fr for fr in frames_ if any(i["active"] for i in fr.get("instances", []))]
    control_ms = sum(fr["control_ms"] for fr in active)
    simulation_ms = sum(fr["simulation_ms"] for fr in active)
    return {
        "control_ms": control_ms / len(active) if active else None,
        "control_pct": 100 * control_ms / simulation_ms if simulation_ms > 0 else None,
        "us": s["summary"]["us_per_particle_step"],
        "wall_s": s["summary"]["wall_s"],
        "substeps": sum(fr["substeps"] for fr in frames_),
        "iterations": sum(fr["divergence_iterations"] + fr["density_iterations"] for fr in frames_),
        "particles": frames_[-1]["particles"],
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene")
    ap.add_argument("--old", required=True)
    ap.add_argument("--new", required=True)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", type=int, default=0, help="OpenMP threads (default: all)")
    ap.add_argument("--particle-radius", type=float, default=0)
    a = ap.parse_args()
    for b in (a.old, a.new):
        if not os.access(b, os.X_OK):
            sys.exit(f"error: {b} is not an executable")
    res = {"old": [], "new": []}
    for k in range(a.repeat):
        for which in (("old", "new") if k % 2 == 0 else ("new", "old")):
            r = run(getattr(a, which), a.scene, a.frames, a.threads, a.particle_radius)
            res[which].append(r)
            print(f"run {k + 1}/{a.repeat} {which}: {r['us']:.3f} us/particle-step, {r['wall_s']:.2f} s", file=sys.stderr, flush=True)
    med = {w: statistics.median(r["us"] for r in res[w]) for w in res}
    spread = {w: (min(r["us"] for r in res[w]), max(r["us"] for r in res[w])) for w in res}
    print(f"scene {a.scene}, {a.frames} frames, {res['new'][0]['particles']} particles, threads {a.threads or 'all'}, load {os.getloadavg()[0]:.1f}")
    for w in ("old", "new"):
        r = res[w][0]
        print(f"{w}: {med[w]:.3f} us/particle-step median (range {spread[w][0]:.3f}-{spread[w][1]:.3f}), "
              f"{r['substeps']} substeps, {r['iterations']} solver iterations")
    print(f"new / old: {med['new'] / med['old']:.3f}")
    if res["new"][0]["control_ms"] is not None and res["old"][0]["control_ms"] is not None:
        for w in ("old", "new"):
            ms = statistics.median(r["control_ms"] for r in res[w])
            pct = [r["control_pct"] for r in res[w]]
            print(f"{w}: control {ms:.3f} ms per active frame median, {statistics.median(pct):.2f} % of the simulation "
                  f"(range {min(pct):.2f}-{max(pct):.2f} %)")
        # Runs k of old and new are neighbours in time: their ratio cancels
        # most of a change in the machine's speed.
        paired = [n["control_ms"] / o["control_ms"] for o, n in zip(res["old"], res["new"])]
        print(f"control new / old, paired runs: {statistics.median(paired):.3f} median "
              f"(range {min(paired):.3f}-{max(paired):.3f})")
    same = res["old"][0]["substeps"] == res["new"][0]["substeps"] and res["old"][0]["iterations"] == res["new"][0]["iterations"]
    print("same work: yes" if same else "same work: NO (substeps or iterations differ: the physics changed, not only the speed)")


if __name__ == "__main__":
    main()
