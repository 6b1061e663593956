#!/usr/bin/env python3
"""SPHERIC Test 2, a 3D dam break against a box (Kleefsman et al. 2005 [KFV*05]): the water height at the
experiment's four gauges, simulated against measured. Runs `flowclip run` on
scenes/validation/spheric_test2.json (exporting every frame), reads the export and writes a report
(markdown + JSON: machine, date, command, figures; and an SVG of the four gauges).

Usage: tools/spheric2.py [--radius R] [--seconds S] [--threads N] [--boundary MODEL] [--out bench/spheric2]
(`make bench-spheric2`). Not part of `make test`: the scene's resolution takes minutes.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py
import numpy as np

from bench_report import loadavg, machine  # tools/, beside this script

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "scenes" / "validation" / "spheric_test2.json"
DATA = ROOT / "bench" / "data" / "spheric_test2_gauges.csv"
# The gauges' positions in the scene's frame (x along the tank from the wall behind the box, z
# across it; the reservoir fills x > 1.992 m): the experiment's gauges, named by where they stand.
GAUGES = {"x0.496": (0.496, 0.5), "x0.992": (0.992, 0.5), "x1.488": (1.488, 0.5), "x2.638": (2.638, 0.5)}
# Water above this height at a gauge counts as the front's arrival there.
ARRIVAL = 0.02


def read_gauges(path: Path = DATA) -> dict[str, np.ndarray]:
    """The measured heights: {"t": seconds, gauge name: metres}, '#' lines skipped."""
    lines = [line for line in path.read_text().splitlines() if line and not line.startswith("#")]
    header = lines[0].split(",")
    if header != ["t"] + list(GAUGES):
        raise ValueError(f"{path}: expected the header {','.join(['t'] + list(GAUGES))}, got {lines[0]}")
    table = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    if table.ndim != 2 or table.shape[1] != len(header) or not np.all(np.diff(table[:, 0]) > 0):
        raise ValueError(f"{path}: rows must have {len(header)} numbers and increasing times")
    return {name: table[:, k] for k, name in enumerate(header)}


def column_top(ys: np.ndarray, r: float) -> float:
    """The water height over the floor (y = 0) from the heights of the particles near a gauge:
    the top (y + r) of the liquid that reaches up from the floor without a gap of more than two
    diameters; spray above such a gap is not water standing at the gauge (0: no water at the floor)."""
    ys = np.sort(ys)
    if len(ys) == 0 or ys[0] - r > 4 * r:
        return 0.0
    top = ys[0]
    for y in ys[1:]:
        if y - top > 4 * r:
            break
        top = y
    return float(top) + r


def gauge_heights(export: Path) -> dict[str, np.ndarray]:
    """Per exported frame, the water height at each gauge: column_top of the liquid particles
    within 2r of the gauge's vertical line."""
    with h5py.File(export, "r") as h5:
        r = float(h5.attrs["particle_radius"])
        offsets, times = h5["frames/offset"][:], h5["frames/time"][:]
        out = {"t": times, **{name: np.zeros(len(times)) for name in GAUGES}}
        for f in range(len(times)):
            a, b = int(offsets[f]), int(offsets[f + 1])
            pos, kind = h5["particles/position"][a:b], h5["particles/kind"][a:b]
            liquid = pos[kind != 2]
            for name, (gx, gz) in GAUGES.items():
                near = (liquid[:, 0] - gx) ** 2 + (liquid[:, 2] - gz) ** 2 <= (2 * r) ** 2
                out[name][f] = column_top(liquid[near, 1], r)
    return out


def arrival(t: np.ndarray, h: np.ndarray) -> float | None:
    """The first time the height passes ARRIVAL (None: never)."""
    above = np.nonzero(h > ARRIVAL)[0]
    return float(t[above[0]]) if len(above) else None


def compare(sim: dict[str, np.ndarray], exp: dict[str, np.ndarray]) -> dict[str, dict]:
    """Per gauge over the simulated span: RMS and mean of (simulated - measured) at the measured
    times, the arrival times of both, the measured mean height."""
    span = (exp["t"] >= sim["t"][0]) & (exp["t"] <= sim["t"][-1])
    t = exp["t"][span]
    out = {}
    for name in GAUGES:
        diff = np.interp(t, sim["t"], sim[name]) - exp[name][span]
        out[name] = {"rms_m": float(np.sqrt(np.mean(diff ** 2))), "bias_m": float(np.mean(diff)),
                     "measured_mean_m": float(np.mean(exp[name][span])),
                     "arrival_s": arrival(sim["t"], sim[name]), "measured_arrival_s": arrival(exp["t"], exp[name]),
                     "points": int(span.sum())}
    return out


def plot(sim, exp, path: Path, title: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 2, figsize=(10, 6), sharex=True)
    for ax, name in zip(axes.flat, GAUGES):
        ax.plot(exp["t"], exp[name], "k-", lw=1, label="experiment (MARIN)")
        ax.plot(sim["t"], sim[name], "C0-", lw=1, label="FlowClip")
        ax.set_title(f"gauge at x = {GAUGES[name][0]} m")
        ax.set_ylabel("water height, m")
        ax.set_xlim(0, sim["t"][-1])
    for ax in axes[1]:
        ax.set_xlabel("t, s")
    axes[0][0].legend(loc="upper right", fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    tmp = path.with_name(f".{path.name}.tmp")
    fig.savefig(tmp, format="svg", metadata={"Date": None})
    plt.close(fig)
    os.replace(tmp, path)


def markdown(report: dict) -> str:
    m, s = report["machine"], report["settings"]
    lines = ["# SPHERIC Test 2: water heights at the gauges", "",
             f"- date: {report['date']}", f"- machine: {m['cpu']}, {m['cores']} cores, load {m['loadavg_at_start']}",
             f"- command: `{report['command']}`",
             f"- run: {s['particles']} particles (r = {s['radius']:.4g} m), boundary {s['boundary']}, {s['seconds']} s "
             f"simulated in {report['wall_s']:.0f} s wall on {s['threads']} threads",
             "", "Per gauge, over the simulated span: the simulated height (the top of the liquid standing "
             "on the floor within 2r of the gauge, spray above a gap of two diameters left out) minus the "
             "measured one at the experiment's samples (RMS and mean), and when water first stands 2 cm "
             "high there.", "",
             "| gauge | measured mean height, m | RMS, m | bias, m | arrival, s (measured) |",
             "|---|---:|---:|---:|---:|"]
    for name, g in report["gauges"].items():
        arrive = "-" if g["arrival_s"] is None else f"{g['arrival_s']:.3f}"
        measured = "-" if g["measured_arrival_s"] is None else f"{g['measured_arrival_s']:.3f}"
        lines.append(f"| x = {GAUGES[name][0]} m | {g['measured_mean_m']:.3f} | {g['rms_m']:.4f} | "
                     f"{g['bias_m']:+.4f} | {arrive} ({measured}) |")
    lines += ["", "![the four gauges](spheric2.svg)", ""]
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--radius", type=float, help="particle radius, m (default: the scene's)")
    ap.add_argument("--seconds", type=float, default=6.0, help="simulated seconds (default 6, the experiment's span)")
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1, help="OpenMP threads")
    ap.add_argument("--boundary", help="boundary model (default: the scene's)")
    ap.add_argument("--out", default="bench/spheric2", help="report folder (default bench/spheric2)")
    ap.add_argument("--binary", default=os.environ.get("FLOWCLIP_BIN", str(ROOT / "build" / "flowclip")))
    args = ap.parse_args()
    exp = read_gauges()
    out = (ROOT / args.out) if not Path(args.out).is_absolute() else Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    started = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    info = machine()
    with tempfile.TemporaryDirectory() as tmp:
        export, stats = Path(tmp) / "frames.h5", Path(tmp) / "stats.json"
        cmd = [args.binary, "run", str(SCENE), "--seconds", str(args.seconds), "--threads", str(args.threads),
               "--export", str(export), "--stats", str(stats)]
        if args.radius:
            cmd += ["--particle-radius", str(args.radius)]
        if args.boundary:
            cmd += ["--boundary", args.boundary]
        t0 = datetime.datetime.now()
        subprocess.run(cmd, check=True)  # its progress line is the terminal's
        wall = (datetime.datetime.now() - t0).total_seconds()
        summary = json.loads(stats.read_text())["summary"]
        with h5py.File(export, "r") as h5:
            radius = float(h5.attrs["particle_radius"])
        sim = gauge_heights(export)
    report = {"date": started, "machine": info, "command": " ".join(["tools/spheric2.py"] + sys.argv[1:]),
              "settings": {"radius": radius, "seconds": args.seconds, "threads": args.threads,
                           "boundary": args.boundary or "the scene's",
                           "particles": summary.get("liquid_particles")},
              "wall_s": wall, "loadavg_at_end": loadavg(), "gauges": compare(sim, exp),
              "simulated": {k: [round(float(v), 5) for v in vals] for k, vals in sim.items()}}
    plot(sim, exp, out / "spheric2.svg", f"SPHERIC Test 2, r = {radius} m")
    for name, text in (("spheric2.md", markdown(report)), ("spheric2.json", json.dumps(report, indent=1) + "\n")):
        tmp = out / f".{name}.tmp"
        tmp.write_text(text)
        os.replace(tmp, out / name)
    print(f"report: {out / 'spheric2.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
