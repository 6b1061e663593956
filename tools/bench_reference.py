#!/usr/bin/env python3
"""Times SPlisHSPlasH and flowclip on the same dam breaks, alternating runs on
this machine, and writes each one's µs per particle-step and wall seconds
per simulated second with our share of SPlisHSPlasH's into a report
(reference.md and reference.json: machine, date, command, every run).

    build/venv/bin/python tools/bench_reference.py                 # all four scenes/bench scenes, once each, into bench/reference
    build/venv/bin/python tools/bench_reference.py --only 3d_r0125 --repeat 3 --out /tmp/ref
    build/venv/bin/python tools/bench_reference.py --only 3d_r005 --seconds 0.1 --out bench/reference-1m
    build/venv/bin/python tools/bench_reference.py --only 3d_r005 --seconds 0.1 --subcycle-viscosity --out bench/reference-1m-subcycled
    build/venv/bin/python tools/bench_reference.py --audit-frames 0    # no density audit

Why: figures read on different machines, or on one virtual machine at
different times, do not divide (the same executable ran up to 1.7x slower
on one host than on another), so FlowClip's figures can only be compared
with SPlisHSPlasH's taken on the same machine in the same hour. This script
takes both (docs/benchmarks/solver.md).

SPlisHSPlasH comes from its own wheel on PyPI (pysplishsplash, pinned
below: single precision, OpenMP, the AVX code paths; not a -march=native
build), installed into build/splishsplash-venv on
first use. Nothing of it is in this repository. Its scenes are written from
the DamBreakModel.json and DamBreakModel_2D.json it ships, with the
settings read from our reference scenes (scenes/bench/): particle radius,
DFSPH density and divergence tolerances, CFL factor, step limit, gravity,
rest density and standard viscosity (`reference_scene`); its tank, block
and volume-map boundaries stay its own, and the 2D scene's micropolar
vorticity is switched off, since ours has none. Our block of liquid is
moved to where its shipped block stands (`at_reference_block`: our
particles on its particles; its block starts a few centimetres above the
floor and from the back wall, and falls first), so that both simulate the
same dam break.
Both run 2 threads. SPlisHSPlasH's time is the sum of its own SimStep
timer (initialisation excluded, as ours); its steps are counted by a
per-step callback.

The density each code holds is then measured from its own exported frames
by tools/density_audit.py (its own SPH sums over the liquid's positions,
neither solver's estimate): one more, untimed run of each per scene, with
FlowClip's HDF5 export and SPlisHSPlasH's VTK one at the same times.
"""
import argparse
import datetime
import json
import os
import re
import shlex
import statistics
import subprocess
import sys
import tempfile

import density_audit  # tools/, beside this script
from bench_report import loadavg, machine

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
WHEEL = "pysplishsplash==2.19.0"

# name: (our reference scene, the SPlisHSPlasH scene it is written from, a
# particle radius in place of the scene's or None)
SCENES = {
    "3d_r010": ("scenes/bench/dambreak3d_r010.json", "DamBreakModel.json", None),
    "3d_r0125": ("scenes/bench/dambreak3d_r0125.json", "DamBreakModel.json", None),
    "2d_r010": ("scenes/bench/dambreak2d_r010.json", "DamBreakModel_2D.json", None),
    "2d_r005": ("scenes/bench/dambreak2d_r005.json", "DamBreakModel_2D.json", None),
    # 941 192 particles (98³): run on its own with a short --seconds.
    "3d_r005": ("scenes/bench/dambreak3d_r010.json", "DamBreakModel.json", 0.005),
}
DEFAULT = ["3d_r010", "3d_r0125", "2d_r010", "2d_r005"]

# Runs inside SPlisHSPlasH's venv: argv = scene, simulated seconds, output directory.
DRIVER = r"""
import json, resource, sys
import pysplishsplash as sph
scene, seconds = sys.argv[1], float(sys.argv[2])
base = sph.Exec.SimulatorBase()
base.init(["splash", "--no-gui", "--no-cache", "--no-initial-pause", "--output-dir", sys.argv[3],
           "--stopAt", str(seconds), scene], "reference")
state = {"steps": 0, "particles": 0}
def step():
    if state["steps"] == 0:
        model = sph.Simulation.getCurrent().getFluidModel(0)
        state["particles"] = model.numActiveParticles()
        state["mass"] = model.getMass(0)
    state["steps"] += 1
base.setTimeStepCB(step)
base.run()
state["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print("DRIVER " + json.dumps(state), flush=True)
"""


def venv_python(build):
    venv = os.path.join(build, "splishsplash-venv")
    py = os.path.join(venv, "bin", "python")
    if not os.path.exists(py):
        print(f"installing {WHEEL} into {venv}", file=sys.stderr, flush=True)
        subprocess.run([sys.executable, "-m", "venv", venv], check=True)
        subprocess.run([py, "-m", "pip", "install", "-q", WHEEL], check=True)
    # The wheel bundles its own libGLdispatch/libGLX/libOpenGL; loaded next to
    # Debian's libGLX (which Chromium brings) they crash at import
    # (__glDispatchInit). Debian's copies serve instead.
    libs = subprocess.run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    bundled = os.path.join(libs, "pysplishsplash.libs")
    system = "/lib/x86_64-linux-gnu"
    for name in os.listdir(bundled):
        m = re.match(r"(libGLdispatch|libGLX|libOpenGL)-[0-9a-f]+\.so\.0", name)
        path = os.path.join(bundled, name)
        if m and not os.path.islink(path) and os.path.exists(os.path.join(system, m.group(1) + ".so.0")):
            os.replace(path, path + ".bundled")
            os.symlink(os.path.join(system, m.group(1) + ".so.0"), path)
    data = os.path.join(venv, "bin", "data")
    return py, data


def reference_scene(ours, shipped):
    """SPlisHSPlasH's shipped scene `shipped` (a dict) with the settings of
    our scene `ours` (a dict, scenes/bench/*.json): the same particle radius,
    DFSPH tolerances, CFL factor, step limit, gravity, rest density and
    viscosity. Its tank and block stay its own (ours copy them). A scene of
    another solver is a ValueError."""
    settings = ours.get("settings", {})
    solver = ours["solver"]
    if solver.get("method") != "dfsph":
        raise ValueError(f"{ours.get('name')}: the reference runs DFSPH, the scene names {solver.get('method')}")
    (phase,) = ours["phases"]
    s = json.loads(json.dumps(shipped))
    c = s["Configuration"]
    c.update({"particleRadius": ours["particle_radius"], "cflMethod": 1, "cflFactor": settings["cfl_factor"],
              "cflMaxTimeStepSize": settings["dt_max"], "pause": False,
              "gravitation": list(ours["gravity"]) + [0] * (3 - len(ours["gravity"]))})
    c["DFSPH"].update({"maxError": solver["density_tolerance_pct"], "maxErrorV": solver["divergence_tolerance_pct"],
                       "enableDivergenceSolver": True})
    for m in s["Materials"]:
        # Ours has no vorticity model: the 2D scene's micropolar one goes.
        m.pop("vorticityMethod", None)
        m["density0"] = phase["rest_density"]
        m["viscosityMethod"] = 1
        m["Standard viscosity"] = {"viscosity": phase["viscosity"]}
    return s


def at_reference_block(ours, shipped):
    """Our scene `ours` (a dict; a copy is returned) with its block of
    liquid where SPlisHSPlasH's `shipped` scene puts its own, particle on
    particle: its particles sit at start + 2r + 2r j (j below round((end -
    start) / 2r) - 1, the block scaled and translated) in its tank (the
    wall: a unit box scaled and translated), whose lower corner is our
    domain's; ours at min + r + 2r i."""
    s = json.loads(json.dumps(ours))
    r, dim = s["particle_radius"], s["dimension"]
    (block,) = s["fluid_blocks"]
    (tank,) = [b for b in shipped["RigidBodies"] if b.get("isWall")]
    tank_min = [t - 0.5 * k for t, k in zip(tank.get("translation", [0, 0, 0]), tank["scale"])]
    (theirs,) = shipped["FluidBlocks"]
    scale, move = theirs.get("scale", [1, 1, 1]), theirs.get("translation", [0, 0, 0])
    for d in range(dim):
        lo, hi = (theirs[k][d] * scale[d] + move[d] for k in ("start", "end"))
        steps = round((hi - lo) / (2 * r)) - 1
        first = lo + 2 * r - tank_min[d] + s["domain"]["min"][d]
        block["min"][d] = first - r
        block["max"][d] = first - r + steps * 2 * r
        if not s["domain"]["min"][d] <= block["min"][d] < block["max"][d] <= s["domain"]["max"][d]:
            raise ValueError(f"{s.get('name')}: SPlisHSPlasH's block lies outside our domain on axis {d}")
    return s


def our_scene(name):
    """Our scene of SCENES[name] (a dict), at its particle radius."""
    ours_path, _, radius = SCENES[name]
    with open(os.path.join(ROOT, ours_path)) as fh:
        ours = json.load(fh)
    if radius is not None:
        ours["particle_radius"] = radius
    return ours


def shipped_scene(data, name):
    with open(os.path.join(data, "Scenes", SCENES[name][1])) as fh:
        return json.load(fh)


def write_reference_scene(data, name, path, export_fps=None):
    """SPlisHSPlasH's scene for SCENES[name] into `path`; with `export_fps`,
    exporting its liquid's positions (VTK) at that rate."""
    s = reference_scene(our_scene(name), shipped_scene(data, name))
    if export_fps:
        s["Configuration"].update({"enableVTKExport": True, "dataExportFPS": export_fps})
    for b in s["RigidBodies"]:
        b["geometryFile"] = os.path.join(data, "models", os.path.basename(b["geometryFile"]))
    with open(path, "w") as fh:
        json.dump(s, fh, indent=1)


def parse_reference_output(out):
    """The figures of one SPlisHSPlasH run from what the driver printed: its
    own timing summary (SimStep, step sizes, iterations) and the driver's
    DRIVER line (steps counted, fluid particles, peak RSS)."""
    def number(label):
        m = re.search(re.escape(label) + r":\s*([0-9.eE+-]+)", out)
        if not m:
            raise RuntimeError(f"SPlisHSPlasH printed no '{label}'")
        return float(m.group(1))
    if "DRIVER " not in out:
        raise RuntimeError("the SPlisHSPlasH driver printed no result line")
    state = json.loads(out.split("DRIVER ", 1)[1].splitlines()[0])
    step_ms = number("Time sum: SimStep")
    simulated = number("Total number: Time step size")
    steps, n = state["steps"], state["particles"]
    if steps <= 0 or n <= 0 or simulated <= 0:
        raise RuntimeError(f"SPlisHSPlasH ran {steps} steps of {n} particles over {simulated} s")
    return {
        "particles": n,
        "steps": steps,
        "simulated_s": simulated,
        "us_per_particle_step": step_ms * 1e3 / (steps * n),
        "wall_s_per_simulated_s": step_ms / 1e3 / simulated,
        "density_iterations_per_step": number("Average number: DFSPH - iterations"),
        "divergence_iterations_per_step": number("Average number: DFSPH - iterationsV"),
        "peak_rss_mb": state["peak_rss_mb"],
        "mass": state.get("mass"),
    }


def run_reference(py, scene, seconds, threads, workdir):
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    out = subprocess.run([py, "-c", DRIVER, scene, str(seconds), workdir], env=env, check=True,
                         capture_output=True, text=True, cwd=workdir).stdout
    return parse_reference_output(out)


def subcycled(scene):
    """`scene` (a dict) with its standard viscosity sub-cycled: its step is
    then bounded by the velocity CFL alone, as SPlisHSPlasH's is."""
    s = json.loads(json.dumps(scene))
    s["effects"] = [{**(e if isinstance(e, dict) else {"name": e}), "subcycle": True}
                    if (e if isinstance(e, str) else e.get("name")) == "viscosity_standard" else e
                    for e in s.get("effects", [])]
    return s


def our_run_scene(data, name, subcycle=False):
    """Our scene of SCENES[name] as it runs beside SPlisHSPlasH (a dict): at
    its radius, the block where SPlisHSPlasH's stands, the viscosity
    sub-cycled if asked."""
    s = at_reference_block(our_scene(name), shipped_scene(data, name))
    return subcycled(s) if subcycle else s


def run_ours(binary, name, scene, seconds, threads, export=None):
    """`flowclip run` of the scene dict `scene`, written beside SCENES[name]'s
    file (so that its relative paths still resolve)."""
    with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as f:
        stats = f.name
    with tempfile.NamedTemporaryFile("w", suffix=".json", prefix=".reference-", delete=False,
                                     dir=os.path.dirname(os.path.join(ROOT, SCENES[name][0]))) as fh:
        json.dump(scene, fh)
        scene_file = fh.name
    try:
        subprocess.run([binary, "run", scene_file, "--seconds", str(seconds), "--threads", str(threads), "--stats",
                        stats, "--quiet"] + ([] if export is None else ["--export", export]), check=True, cwd=ROOT)
        with open(stats) as fh:
            s = json.load(fh)
    finally:
        os.unlink(stats)
        os.unlink(scene_file)
    frames, summary = s["frames"], s["summary"]
    steps = summary["substeps"]
    return {
        "particles": summary["liquid_particles"],
        "steps": steps,
        "simulated_s": summary["simulated_s"],
        "us_per_particle_step": summary["us_per_particle_step"],
        "wall_s_per_simulated_s": summary["wall_s_per_simulated_s"],
        "density_iterations_per_step": sum(f["density_iterations"] for f in frames) / steps,
        "divergence_iterations_per_step": sum(f["divergence_iterations"] for f in frames) / steps,
        "peak_rss_mb": summary["peak_rss_mb"],
    }


def audit_scene(py, data, name, seconds, threads, binary, frames, work, subcycle=False):
    """One untimed run of each code on SCENES[name], exporting about `frames`
    frames at the same times, measured by tools/density_audit.py:
    {"flowclip": summary, "splishsplash": summary, "density_tolerance_pct"}."""
    ours = our_run_scene(data, name, subcycle)
    fps = frames / seconds
    every = max(1, round(ours["settings"]["frame_rate"] / fps))
    fps = ours["settings"]["frame_rate"] / every  # both at the times of our every-th frame
    out = {"density_tolerance_pct": ours["solver"]["density_tolerance_pct"]}
    h5 = os.path.join(work, name + "-audit.h5")
    try:
        run_ours(binary, name, ours, seconds, threads, export=h5)
        r, dim, rest, ours_frames = density_audit.read_h5(h5, every)
    finally:
        if os.path.exists(h5):
            os.unlink(h5)
    out["flowclip"] = density_audit.summarise(ours_frames, r, density_audit.flowclip_mass(r, dim, rest), rest)
    ref_dir = os.path.join(work, name + "-audit")
    os.makedirs(ref_dir, exist_ok=True)
    scene = os.path.join(ref_dir, "scene.json")
    write_reference_scene(data, name, scene, export_fps=fps)
    figures = run_reference(py, scene, seconds, threads, ref_dir)
    files = [os.path.join(ref_dir, "vtk", f) for f in os.listdir(os.path.join(ref_dir, "vtk"))]
    # Its first file is the state at t = 0, which ours does not export.
    ref_frames = [(t, x) for t, x in density_audit.vtk_frames(files, fps, dim) if t > 0]
    out["splishsplash"] = density_audit.summarise(ref_frames, r, figures["mass"], rest)
    for f in files:
        os.unlink(f)
    return out


def audit_table(audits):
    lines = ["| scene | tolerance | frames (FlowClip / SPlisHSPlasH) | interior share | mean deviation | "
             "mean compression | 99th percentile | worst frame's mean compression |",
             "|---|---:|---|---|---|---|---|---|"]
    for name, a in audits.items():
        o, r = a["flowclip"], a["splishsplash"]
        def both(key, fmt="{:.3f} %"):
            return f"{fmt.format(o[key])} / {fmt.format(r[key])}"
        lines.append(f"| {name} | {a['density_tolerance_pct']:g} % | {len(o['frames'])} / {len(r['frames'])} "
                     f"| {both('interior_share', '{:.2f}')} | {both('mean_deviation_pct')} "
                     f"| {both('mean_compression_pct')} | {both('p99_compression_pct')} "
                     f"| {both('max_mean_compression_pct')} |")
    return lines


def spread(values, fmt):
    lo, hi, med = min(values), max(values), statistics.median(values)
    return fmt.format(med) if lo == hi else (fmt + " ({}–{})").format(med, fmt.format(lo), fmt.format(hi))


# At most half of SPlisHSPlasH's µs per particle-step and wall time per simulated second.
TARGET_PCT = 50.0
# At the paper's sizes (100k particles and more): at most 30 % of its wall time per simulated second.
LARGE_PARTICLES = 100_000
LARGE_TARGET_PCT = 30.0


def large_target(scenes):
    """The paper-size target over `scenes` (name: runs with their ratios):
    {met, worst_pct, scene} over the scenes of at least LARGE_PARTICLES of
    ours, or None when there is none."""
    large = {name: max(s["ratios"]["wall_pct"]) for name, s in scenes.items()
             if s["flowclip"][0]["particles"] >= LARGE_PARTICLES}
    if not large:
        return None
    worst = max(large, key=large.get)
    return {"min_particles": LARGE_PARTICLES, "max_wall_pct": LARGE_TARGET_PCT,
            "met": large[worst] <= LARGE_TARGET_PCT, "worst_pct": large[worst], "scene": worst}


def ratios(runs):
    """Our share of SPlisHSPlasH's figures, pair by pair (percent)."""
    o, r = runs["flowclip"], runs["splishsplash"]
    return {"us_pct": [100 * a["us_per_particle_step"] / b["us_per_particle_step"] for a, b in zip(o, r)],
            "wall_pct": [100 * a["wall_s_per_simulated_s"] / b["wall_s_per_simulated_s"] for a, b in zip(o, r)]}


def table(results):
    lines = ["| scene | particles (FlowClip / SPlisHSPlasH) | steps | density / divergence iterations per step "
             "| µs / particle-step (FlowClip vs SPlisHSPlasH) | wall s / simulated s | peak RSS MB "
             "| FlowClip / SPlisHSPlasH: µs, wall |",
             "|---|---|---|---|---|---|---|---|"]
    for name, runs in results.items():
        o, r = runs["flowclip"], runs["splishsplash"]
        q = ratios(runs)
        lines.append(
            f"| {name} | {o[0]['particles']} / {r[0]['particles']} | {o[0]['steps']} / {r[0]['steps']} "
            f"| {o[0]['density_iterations_per_step']:.2f} / {o[0]['divergence_iterations_per_step']:.2f} vs "
            f"{r[0]['density_iterations_per_step']:.2f} / {r[0]['divergence_iterations_per_step']:.2f} "
            f"| {spread([x['us_per_particle_step'] for x in o], '{:.3f}')} vs "
            f"{spread([x['us_per_particle_step'] for x in r], '{:.3f}')} "
            f"| {spread([x['wall_s_per_simulated_s'] for x in o], '{:.1f}')} vs "
            f"{spread([x['wall_s_per_simulated_s'] for x in r], '{:.1f}')} "
            f"| {max(x['peak_rss_mb'] for x in o):.0f} vs {max(x['peak_rss_mb'] for x in r):.0f} "
            f"| {spread(q['us_pct'], '{:.1f}')} %, {spread(q['wall_pct'], '{:.1f}')} % |")
    return lines


def write_report(out, report):
    """reference.md and reference.json into `out`, each replaced whole."""
    worst = max((max(v) for s in report["scenes"].values() for v in s["ratios"].values()), default=float("nan"))
    met = report["target"]["met"]
    md = ["# SPlisHSPlasH beside FlowClip on the same dam breaks", "",
          f"- date: {report['date']}",
          f"- machine: {report['machine']['cpu']}, {report['machine']['cores']} cores, "
          f"load average at start {report['machine']['loadavg_at_start']}, at end {report['loadavg_at_end']}",
          f"- command: `{report['command']}`",
          f"- SPlisHSPlasH: {report['settings']['reference']} (its PyPI wheel); FlowClip: "
          f"`{report['settings']['flowclip']}` {report['settings']['flowclip_version']}",
          "- the same dam break: FlowClip's block of liquid moved onto SPlisHSPlasH's shipped one, particle on "
          "particle (`at_reference_block`)",
          f"- {report['settings']['threads']} threads each, {report['settings']['seconds']:g} simulated s per run, "
          f"{report['settings']['repeat']} alternating pair(s) of runs per scene"
          + ("; FlowClip's standard viscosity sub-cycled (`subcycle`)"
             if report["settings"].get("subcycle_viscosity") else ""), "",
          "Medians, with the range over the pairs in brackets; the last column divides each pair's figures.", ""]
    md += table(report["scenes_runs"])
    md += ["", f"Target: at most {TARGET_PCT:g} % of SPlisHSPlasH's µs per particle-step and wall time per "
           f"simulated second on every scene: **{'met' if met else 'not met'}** (worst pair {worst:.1f} %)."]
    audits = report.get("density_audit")
    if audits:
        md += ["", "## The density each code holds, measured from its exported frames", "",
               "Each scene run once more by each code, untimed, exporting its liquid's positions at the same times "
               "(FlowClip's HDF5, SPlisHSPlasH's VTK); `tools/density_audit.py` sums the density of every particle "
               "from those positions alone (cubic spline of support 4r, each code's particle mass) and keeps the "
               f"interior ones: those whose kernel-weighted neighbour centroid is within "
               f"{density_audit.CENTROID_LIMIT:g} r of them (the walls' share is in neither file). Figures are the "
               "mean over the frames, FlowClip / SPlisHSPlasH; compression is the positive part of the deviation "
               "from the rest density, as DFSPH's tolerance bounds it.", ""]
        md += audit_table(audits)
    large = report["target"].get("large")
    if large:
        md += ["", f"Target at {large['min_particles']:,} particles and more: at most {large['max_wall_pct']:g} % of "
               f"SPlisHSPlasH's wall time per simulated second: **{'met' if large['met'] else 'not met'}** "
               f"(worst pair {large['worst_pct']:.1f} %, {large['scene']})."]
    os.makedirs(out, exist_ok=True)
    body = {k: v for k, v in report.items() if k != "scenes_runs"}
    for name, text in (("reference.md", "\n".join(md) + "\n"), ("reference.json", json.dumps(body, indent=1) + "\n")):
        tmp = os.path.join(out, "." + name + ".tmp")
        with open(tmp, "w") as fh:
            fh.write(text)
        os.replace(tmp, os.path.join(out, name))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="+", choices=sorted(SCENES),
                    help="scenes to run (default: " + ", ".join(DEFAULT) + "; 3d_r005 is a million particles)")
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per run")
    ap.add_argument("--repeat", type=int, default=1, help="alternating pairs of runs per scene")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--binary", default=os.path.join(ROOT, "build", "flowclip"))
    ap.add_argument("--subcycle-viscosity", action="store_true",
                    help="run our scenes' standard viscosity sub-cycled (its `subcycle` parameter), so that it does "
                         "not bound the step, as SPlisHSPlasH's does not")
    ap.add_argument("--audit-frames", type=int, default=5,
                    help="measure each code's density from this many exported frames per scene, in one more untimed "
                         "run of each (tools/density_audit.py; 0: none)")
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "reference"),
                    help="report folder: reference.md and reference.json (default bench/reference)")
    args = ap.parse_args()
    if args.repeat < 1 or args.seconds <= 0 or args.audit_frames < 0:
        ap.error("--repeat must be >= 1, --seconds > 0 and --audit-frames >= 0")

    command = "build/venv/bin/python tools/bench_reference.py" + "".join(" " + shlex.quote(a) for a in sys.argv[1:])
    started = machine()
    date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    version = subprocess.run([args.binary, "--version"], capture_output=True, text=True, check=True).stdout.strip()
    py, data = venv_python(os.path.join(ROOT, "build"))
    names = args.only or DEFAULT
    results, audits = {}, {}
    with tempfile.TemporaryDirectory() as work:
        total = len(names) * (args.repeat * 2 + (1 if args.audit_frames else 0))
        done = 0
        for name in names:
            ours_scene = our_run_scene(data, name, args.subcycle_viscosity)
            ref_scene = os.path.join(work, name + ".json")
            write_reference_scene(data, name, ref_scene)
            runs = {"splishsplash": [], "flowclip": []}
            for k in range(args.repeat):
                # Alternate which goes first, so a drift in the host's speed
                # over the pair does not favour one.
                order = ["splishsplash", "flowclip"] if k % 2 == 0 else ["flowclip", "splishsplash"]
                for who in order:
                    done += 1
                    print(f"[{done}/{total}] {name} {who} ({args.seconds:g} simulated s)", file=sys.stderr, flush=True)
                    r = (run_reference(py, ref_scene, args.seconds, args.threads, work) if who == "splishsplash"
                         else run_ours(args.binary, name, ours_scene, args.seconds, args.threads))
                    runs[who].append(r)
            results[name] = runs
            if args.audit_frames:
                done += 1
                print(f"[{done}/{total}] {name} density audit: both codes, {args.audit_frames} exported frames",
                      file=sys.stderr, flush=True)
                audits[name] = audit_scene(py, data, name, args.seconds, args.threads, args.binary,
                                           args.audit_frames, work, args.subcycle_viscosity)

    sys.stderr.flush()
    print("\n".join(table(results)))
    scenes = {}
    for name, runs in results.items():
        scenes[name] = {"flowclip_scene": SCENES[name][0], "reference_scene": SCENES[name][1],
                        "particle_radius": SCENES[name][2], **runs, "ratios": ratios(runs)}
    met = all(max(v) <= TARGET_PCT for s in scenes.values() for v in s["ratios"].values())
    report = {"benchmark": "reference", "date": date, "command": command, "machine": started,
              "loadavg_at_end": loadavg(),
              "settings": {"threads": args.threads, "seconds": args.seconds, "repeat": args.repeat,
                           "subcycle_viscosity": args.subcycle_viscosity, "audit_frames": args.audit_frames,
                           "reference": WHEEL, "flowclip": os.path.relpath(args.binary, ROOT),
                           "flowclip_version": version},
              "target": {"max_pct_of_reference": TARGET_PCT, "met": met, "large": large_target(scenes)},
              "scenes": scenes, "scenes_runs": results, "density_audit": audits}
    write_report(args.out, report)
    print(f"report: {os.path.join(args.out, 'reference.md')}", file=sys.stderr)


if __name__ == "__main__":
    main()
