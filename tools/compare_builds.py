#!/usr/bin/env python3
"""Times scenes with two flowclip executables, alternating runs so that a
change in the machine's load hits both alike, prints µs per particle-step
(median of the repeats) side by side and, with --out, writes a report
(compare.md and compare.json: machine, date, command, every run).

    build/venv/bin/python tools/compare_builds.py --old OLD/flowclip --new build/flowclip \\
        scenes/dambreak2d.json:60 scenes/dambreak3d.json:20 --repeat 5 --out bench/no_cost

A scene is SCENE or SCENE:FRAMES (default --frames).

It is how "a plain dam break runs no slower than before the effects work"
is measured (docs/benchmarks/solver.md): OLD is a build of the commit
before the change. Both runs must do the same work (same substeps and
solver iterations); the script says so when they do not.

For a scene with template instances it also compares control's time per
frame with an active instance and its share of the simulation's time (as
`flowclip bench control` reports them).
"""
import argparse
import datetime
import json
import os
import shlex
import statistics
import subprocess
import sys
import tempfile

from bench_report import loadavg, machine  # tools/, beside this script


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


def compare(old, new, scene, frames, repeat, threads, radius):
    """Alternating runs of one scene; the figures of both and how they compare."""
    res = {"old": [], "new": []}
    for k in range(repeat):
        for which in (("old", "new") if k % 2 == 0 else ("new", "old")):
            r = run(old if which == "old" else new, scene, frames, threads, radius)
            res[which].append(r)
            print(f"{scene} run {k + 1}/{repeat} {which}: {r['us']:.3f} us/particle-step, {r['wall_s']:.2f} s",
                  file=sys.stderr, flush=True)
    out = {"scene": scene, "frames": frames, "particles": res["new"][0]["particles"], "runs": res}
    for w in ("old", "new"):
        us = [r["us"] for r in res[w]]
        out[w] = {"us_median": statistics.median(us), "us_min": min(us), "us_max": max(us),
                  "substeps": res[w][0]["substeps"], "iterations": res[w][0]["iterations"]}
    out["new_over_old"] = out["new"]["us_median"] / out["old"]["us_median"]
    out["same_work"] = all(res["old"][0][k] == res["new"][0][k] for k in ("substeps", "iterations"))
    if res["new"][0]["control_ms"] is not None and res["old"][0]["control_ms"] is not None:
        # Runs k of old and new are neighbours in time: their ratio cancels
        # most of a change in the machine's speed.
        paired = [n["control_ms"] / o["control_ms"] for o, n in zip(res["old"], res["new"])]
        out["control"] = {w: {"ms_median": statistics.median(r["control_ms"] for r in res[w]),
                              "pct_median": statistics.median(r["control_pct"] for r in res[w])}
                          for w in ("old", "new")}
        out["control"]["new_over_old_paired"] = {"median": statistics.median(paired), "min": min(paired),
                                                 "max": max(paired)}
    return out


def row(c):
    def figure(w):
        f = c[w]
        return f"{f['us_median']:.3f} ({f['us_min']:.3f}–{f['us_max']:.3f})"
    work = (f"yes: {c['new']['substeps']} substeps, {c['new']['iterations']} solver iterations in both"
            if c["same_work"] else
            f"no: {c['old']['substeps']} / {c['new']['substeps']} substeps, "
            f"{c['old']['iterations']} / {c['new']['iterations']} iterations")
    return (f"| `{os.path.basename(c['scene'])}`, {c['frames']} frames | {c['particles']} | {figure('old')} "
            f"| {figure('new')} | {c['new_over_old']:.2f} | {work} |")


def write_report(out, report):
    """compare.md and compare.json into `out`, each replaced whole."""
    md = ["# Two builds on the same scenes", "",
          f"- date: {report['date']}",
          f"- machine: {report['machine']['cpu']}, {report['machine']['cores']} cores, "
          f"load average at start {report['machine']['loadavg_at_start']}, at end {report['loadavg_at_end']}",
          f"- command: `{report['command']}`",
          f"- old: {report['old_label']} (`{report['old']}`); new: {report['new_label']} (`{report['new']}`)",
          f"- threads: {report['threads'] or 'all'}; {report['repeat']} alternating pair(s) of runs per scene", "",
          "µs per particle-step, median (range) over the runs; same work: the same substeps and solver iterations.",
          "", "| scene | particles | old | new | new / old | same work |", "|---|---|---|---|---|---|"]
    md += [row(c) for c in report["scenes"]]
    os.makedirs(out, exist_ok=True)
    for name, text in (("compare.md", "\n".join(md) + "\n"), ("compare.json", json.dumps(report, indent=1) + "\n")):
        tmp = os.path.join(out, "." + name + ".tmp")
        with open(tmp, "w") as fh:
            fh.write(text)
        os.replace(tmp, os.path.join(out, name))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+", metavar="SCENE[:FRAMES]")
    ap.add_argument("--old", required=True)
    ap.add_argument("--new", required=True)
    ap.add_argument("--frames", type=int, default=60, help="frames per run where a scene names none")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", type=int, default=0, help="OpenMP threads (default: all)")
    ap.add_argument("--particle-radius", type=float, default=0)
    ap.add_argument("--out", help="report folder: compare.md and compare.json")
    ap.add_argument("--old-label", default="old", help="what the old executable is, for the report (a commit, a build)")
    ap.add_argument("--new-label", default="new", help="what the new executable is, for the report")
    a = ap.parse_args()
    for b in (a.old, a.new):
        if not os.access(b, os.X_OK):
            sys.exit(f"error: {b} is not an executable")
    if a.repeat < 1:
        ap.error("--repeat must be >= 1")
    jobs = []
    for spec in a.scenes:
        scene, _, frames = spec.rpartition(":") if spec.rpartition(":")[2].isdigit() else (spec, "", "")
        jobs.append((scene, int(frames) if frames else a.frames))
    command = "build/venv/bin/python tools/compare_builds.py" + "".join(" " + shlex.quote(x) for x in sys.argv[1:])
    started = machine()
    date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    results = [compare(a.old, a.new, scene, frames, a.repeat, a.threads, a.particle_radius) for scene, frames in jobs]
    for c in results:
        print(f"scene {c['scene']}, {c['frames']} frames, {c['particles']} particles, threads {a.threads or 'all'}")
        for w in ("old", "new"):
            f = c[w]
            print(f"{w}: {f['us_median']:.3f} us/particle-step median (range {f['us_min']:.3f}-{f['us_max']:.3f}), "
                  f"{f['substeps']} substeps, {f['iterations']} solver iterations")
        print(f"new / old: {c['new_over_old']:.3f}")
        if "control" in c:
            for w in ("old", "new"):
                print(f"{w}: control {c['control'][w]['ms_median']:.3f} ms per active frame median, "
                      f"{c['control'][w]['pct_median']:.2f} % of the simulation")
            p = c["control"]["new_over_old_paired"]
            print(f"control new / old, paired runs: {p['median']:.3f} median (range {p['min']:.3f}-{p['max']:.3f})")
        print("same work: yes" if c["same_work"] else
              "same work: NO (substeps or iterations differ: the physics changed, not only the speed)")
    if a.out:
        write_report(a.out, {"benchmark": "compare_builds", "date": date, "command": command, "machine": started,
                             "loadavg_at_end": loadavg(), "old": a.old, "new": a.new, "old_label": a.old_label,
                             "new_label": a.new_label, "threads": a.threads,
                             "repeat": a.repeat, "scenes": results})
        print(f"report: {os.path.join(a.out, 'compare.md')}", file=sys.stderr)


if __name__ == "__main__":
    main()
