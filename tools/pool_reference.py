#!/usr/bin/env python3
"""Lets the same pool of liquid rest in SPlisHSPlasH and in FlowClip and
writes how fast each one's liquid still moves, the RMS speed and the
fastest particle every 0.1 s, into a report (pool.md and pool.json:
machine, date, command, figures).

    build/venv/bin/python tools/pool_reference.py                      # into bench/pool-reference
    build/venv/bin/python tools/pool_reference.py --viscosity 0 --pairs akinci2012:akinci --out /tmp/rest

The pool: SPlisHSPlasH's 2D dam-break tank (DamBreakModel_2D.json, 4 m
wide) with its block widened to the tank and 1 m deep, so that it rests;
FlowClip's scenes/hydrostatic2d.json in a domain of the tank's size, its
block on SPlisHSPlasH's particle for particle (tools/bench_reference.py's
at_reference_block: both start a diameter from the walls and settle by a
radius). Both carry the scene's particle radius, DFSPH tolerances and
iteration limit, CFL factor, step limit, gravity, rest density and standard
viscosity (each --viscosity in turn), each pair of boundary models in
turn (--pairs OURS:THEIRS). A resting pool should not move; what
still moves after a second is the method's, and this puts FlowClip's
figure beside the reference implementation's
(docs/physics/boundaries.md#what-still-moves-in-a-resting-pool).
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py
import numpy as np

import bench_reference  # tools/, beside this script
import density_audit
from bench_report import report_start, write_report

ROOT = bench_reference.ROOT
SCENE = "scenes/hydrostatic2d.json"
SHIPPED = "DamBreakModel_2D.json"
DEPTH = 1.0  # m
SAMPLE = 0.1  # s between the compared frames
SETTLED = 1.0  # s: the speed reported is the fastest from then on
# SPlisHSPlasH's boundaryHandlingMethod by the name its docs give it.
REFERENCE_BOUNDARIES = {"volume-maps": 2, "akinci": 0}


def shipped_scene(data):
    with open(os.path.join(data, "Scenes", SHIPPED)) as fh:
        return json.load(fh)


def tank(shipped):
    """(lower corner, size) of the shipped scene's wall, a unit box scaled and translated."""
    (wall,) = [b for b in shipped["RigidBodies"] if b.get("isWall")]
    move, scale = wall.get("translation", [0, 0, 0]), wall["scale"]
    return [m - 0.5 * s for m, s in zip(move, scale)], list(scale)


def pool_scenes(ours, shipped, viscosity, boundary, reference_boundary):
    """(our scene, SPlisHSPlasH's scene) as dicts: SPlisHSPlasH's block
    across its tank's width and DEPTH deep, ours in a domain of the tank's
    size with its block on SPlisHSPlasH's particles, both with `viscosity`
    and our scene's settings; `boundary` ours (None: the scene's),
    `reference_boundary` a key of REFERENCE_BOUNDARIES."""
    lo, size = tank(shipped)
    theirs = json.loads(json.dumps(shipped))
    (block,) = theirs["FluidBlocks"]
    block.update({"start": [lo[0], lo[1], -1], "end": [lo[0] + size[0], lo[1] + DEPTH, 1],
                  "translation": [0, 0, 0], "scale": [1, 1, 1]})
    s = json.loads(json.dumps(ours))
    s["phases"][0]["viscosity"] = viscosity
    if viscosity == 0:
        s["effects"] = [e for e in s.get("effects", []) if (e if isinstance(e, str) else e["name"]) != "viscosity_standard"]
    s["domain"] = {"min": [0.0, 0.0], "max": [size[0], size[1]]}
    s["fluid_blocks"] = [{**s["fluid_blocks"][0], "min": [0.0, 0.0], "max": [size[0], DEPTH]}]
    if boundary:
        s["boundary"] = {"method": boundary}
    s = bench_reference.at_reference_block(s, theirs)
    ref = bench_reference.reference_scene(s, theirs)
    c = ref["Configuration"]
    c["boundaryHandlingMethod"] = REFERENCE_BOUNDARIES[reference_boundary]
    c["DFSPH"]["maxIterations"] = s["solver"].get("max_iterations", c["DFSPH"]["maxIterations"])
    c.update({"enableVTKExport": True, "dataExportFPS": 1 / SAMPLE, "particleAttributes": "velocity"})
    return s, ref


def speeds(times, velocities, first=SETTLED):
    """{"time", "rms", "max"} per frame (m/s) and the fastest speed at or after `first` s."""
    rows = []
    for t, v in zip(times, velocities):
        s = np.linalg.norm(np.asarray(v, dtype=np.float64), axis=1)
        rows.append({"time": float(t), "rms": float(np.sqrt((s * s).mean())), "max": float(s.max())})
    settled = [r["max"] for r in rows if r["time"] >= first - 1e-9]
    if not settled:
        raise ValueError(f"no frame at or after {first} s")
    return {"frames": rows, "max_after": max(settled), "rms_at_end": rows[-1]["rms"]}


def our_frames(path, every):
    """(times, velocities) of every `every`-th frame of a FlowClip export."""
    with h5py.File(path, "r") as f:
        times, offsets = f["frames/time"][:], f["frames/offset"][:]
        v = f["particles/velocity"]
        ends = list(offsets[1:]) + [v.shape[0]]
        picked = range(0, len(times), every)
        return [times[i] for i in picked], [v[offsets[i]:ends[i]] for i in picked]


def run_case(py, data, binary, viscosity, boundary, reference_boundary, seconds, threads, work):
    with open(os.path.join(ROOT, SCENE)) as fh:
        ours, ref = pool_scenes(json.load(fh), shipped_scene(data), viscosity, boundary, reference_boundary)
    for b in ref["RigidBodies"]:
        b["geometryFile"] = os.path.join(data, "models", os.path.basename(b["geometryFile"]))
    case = os.path.join(work, f"{boundary}-{reference_boundary}-v{viscosity:g}")
    os.makedirs(case, exist_ok=True)
    scene, ref_scene, h5 = (os.path.join(case, n) for n in ("ours.json", "reference.json", "ours.h5"))
    with open(scene, "w") as fh:
        json.dump(ours, fh)
    with open(ref_scene, "w") as fh:
        json.dump(ref, fh)
    subprocess.run([binary, "run", scene, "--seconds", str(seconds), "--threads", str(threads), "--export", h5,
                    "--quiet"], check=True, cwd=ROOT)
    times, velocities = our_frames(h5, round(ours["settings"]["frame_rate"] * SAMPLE))
    flowclip = speeds(times, velocities)
    flowclip["particles"] = len(velocities[0])
    bench_reference.run_reference(py, ref_scene, seconds, threads, case)
    files = [os.path.join(case, "vtk", f) for f in os.listdir(os.path.join(case, "vtk"))]
    frames = density_audit.vtk_frames(files, 1 / SAMPLE, 3, read=lambda f: density_audit.read_vtk_field(f, "velocity"))
    reference = speeds([t for t, _ in frames], [v for _, v in frames])
    reference["particles"] = len(frames[0][1])
    return {"viscosity": viscosity, "boundary": ours["boundary"]["method"], "reference_boundary": reference_boundary,
            "flowclip": flowclip, "splishsplash": reference}


def markdown(report):
    """The report's pool.md."""
    m = report["machine"]
    lines = ["# A resting pool: what still moves, FlowClip beside SPlisHSPlasH", "",
             f"- date: {report['date']}", f"- command: `{report['command']}`",
             f"- machine: {m.get('cpu', '?')}, {m.get('cores', '?')} cores; load average "
             f"{m.get('loadavg_at_start', '?')} at the start, {report['loadavg_at_end']} at the end",
             f"- SPlisHSPlasH: {report['settings']['reference']}; FlowClip: {report['settings']['flowclip_version']}", "",
             f"A pool {DEPTH:g} m deep across SPlisHSPlasH's 2D dam-break tank (4 m), both codes' blocks particle on "
             "particle a diameter from the walls, with the settings of " + SCENE + " (DFSPH, its tolerances, "
             "CFL factor, step limit and radius) and each viscosity below. Speeds in mm/s; *fastest after "
             f"{SETTLED:g} s*: over the frames from then on, every {SAMPLE:g} s. SPlisHSPlasH's file at t = 0 "
             "already holds velocities (its export's), FlowClip's the start's zeros.", "",
             "| viscosity | FlowClip boundary | SPlisHSPlasH boundary | particles | FlowClip: fastest after "
             f"{SETTLED:g} s | RMS at the end | SPlisHSPlasH: fastest after {SETTLED:g} s | RMS at the end |",
             "|---:|---|---|---:|---:|---:|---:|---:|"]
    for c in report["cases"]:
        f, s = c["flowclip"], c["splishsplash"]
        lines.append(f"| {c['viscosity']:g} | `{c['boundary']}` | {c['reference_boundary']} | "
                     f"{f['particles']} / {s['particles']} | {1e3 * f['max_after']:.1f} | {1e3 * f['rms_at_end']:.1f} "
                     f"| {1e3 * s['max_after']:.1f} | {1e3 * s['rms_at_end']:.1f} |")
    for c in report["cases"]:
        lines += ["", f"## `{c['boundary']}` beside {c['reference_boundary']}, viscosity {c['viscosity']:g}", "",
                  "| t (s) | FlowClip RMS | FlowClip fastest | SPlisHSPlasH RMS | SPlisHSPlasH fastest |",
                  "|---:|---:|---:|---:|---:|"]
        theirs = {round(r["time"], 6): r for r in c["splishsplash"]["frames"]}
        for r in c["flowclip"]["frames"]:
            o = theirs.get(round(r["time"], 6))
            tail = f"{1e3 * o['rms']:.1f} | {1e3 * o['max']:.1f}" if o else "- | -"
            lines.append(f"| {r['time']:.1f} | {1e3 * r['rms']:.1f} | {1e3 * r['max']:.1f} | {tail} |")
    return "\n".join(lines) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per run (more than 1)")
    ap.add_argument("--viscosity", type=float, nargs="+", help="standard viscosities to run (default: the scene's, then 0)")
    ap.add_argument("--pairs", nargs="+", default=["adami2012:volume-maps", "akinci2012:akinci"],
                    help="boundary models side by side, FlowClip's:SPlisHSPlasH's (SPlisHSPlasH's: "
                         + ", ".join(sorted(REFERENCE_BOUNDARIES)) + "; default: adami2012:volume-maps akinci2012:akinci)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--binary", default=os.path.join(ROOT, "build", "flowclip"))
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "pool-reference"))
    args = ap.parse_args()
    if args.seconds <= SETTLED:
        ap.error(f"--seconds must be more than {SETTLED:g}")
    with open(os.path.join(ROOT, SCENE)) as fh:
        viscosities = args.viscosity or [json.load(fh)["phases"][0]["viscosity"], 0.0]
    if any(v < 0 for v in viscosities):
        ap.error("--viscosity must be >= 0")
    pairs = [p.split(":", 1) for p in args.pairs]
    if any(len(p) != 2 or p[1] not in REFERENCE_BOUNDARIES or not p[0] for p in pairs):
        ap.error("--pairs takes OURS:THEIRS, THEIRS one of " + ", ".join(sorted(REFERENCE_BOUNDARIES)))
    report = report_start("tools/pool_reference.py", sys.argv[1:])
    version = subprocess.run([args.binary, "--version"], capture_output=True, text=True, check=True).stdout.strip()
    py, data = bench_reference.venv_python(os.path.join(ROOT, "build"))
    cases = []
    with tempfile.TemporaryDirectory() as work:
        runs = [(ours, theirs, v) for ours, theirs in pairs for v in viscosities]
        for k, (ours, theirs, v) in enumerate(runs):
            print(f"[{k + 1}/{len(runs)}] {ours} beside {theirs}, viscosity {v:g}: both codes, {args.seconds:g} "
                  "simulated s", file=sys.stderr, flush=True)
            cases.append(run_case(py, data, args.binary, v, ours, theirs, args.seconds, args.threads, work))
    report.update({"benchmark": "pool-reference",
                   "settings": {"seconds": args.seconds, "threads": args.threads, "reference": bench_reference.WHEEL,
                                "flowclip_version": version, "scene": SCENE, "depth_m": DEPTH},
                   "cases": cases})
    write_report(Path(args.out), "pool", report, markdown)


if __name__ == "__main__":
    main()
