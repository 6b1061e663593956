#!/usr/bin/env python3
"""Plots of `flowclip bench accuracy` (docs/benchmarks/accuracy.md).

    build/venv/bin/python tools/plot_accuracy.py DIR [--martin-moyce CSV]

Reads DIR/accuracy.csv and DIR/surge_fronts.csv (written by the bench, which
calls this script) and writes
  DIR/pareto.svg       cost (wall s per simulated s) against each error, one
                       panel per error; the Pareto fronts (the bench's
                       front_* columns: one per scene and resolution) drawn
                       as staircases, presets labelled;
  DIR/surge_front.svg  the dam break's surge front Z = x/a against
                       T = t sqrt(2g/a): Martin & Moyce (1952) [MM52] and the
                       presets' runs, with the resolution levels.
The fronts and presets are the bench's (accuracy.csv); nothing is recomputed
here.
"""
from __future__ import annotations

import argparse
import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402

plt.rcParams["svg.fonttype"] = "none"  # text stays text: small, searchable files

# (front column, value column, axis label, transform of the value, x scale)
PANELS = [
    ("front_avg_density_error", "avg_density_error_pct", "average density error (%)", float, "log"),
    ("front_max_density_error", "max_density_error_pct", "largest density error (%)", float, "log"),
    ("front_volume_drift", "volume_drift_pct", "|volume drift| (%)", lambda v: abs(float(v)), "log"),
    ("front_surge_front_rms", "surge_front_rms", "surge front RMS vs Martin & Moyce (Z)", float, "linear"),
    ("front_fidelity", "fidelity_iou", "1 − control fidelity IoU (drop2d)", lambda v: 1 - float(v), "linear"),
]
GROUP_STYLE = {
    "solver": dict(marker="o"),
    "resolution": dict(marker="s"),
    "precision": dict(marker="^"),
    "control": dict(marker="D"),
    "templates": dict(marker="v"),
}
METHOD_COLOR = {"dfsph": "tab:blue", "wcsph": "tab:orange"}


def read_rows(path: Path) -> list[dict]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def label(row: dict) -> str:
    if row["method"] == "dfsph":
        s = f"{row['density_tolerance_pct']}/{row['divergence_tolerance_pct']}%"
    else:
        s = f"B {float(row['stiffness']):g}"
    s += f" cfl {row['cfl_factor']}"
    if row["group"] in ("resolution",):
        s += f" r {row['particle_radius']}"
    if row["group"] == "precision":
        s += " double"
    if row["group"] == "control":
        changed = [k for k, d in (("forces_every_substep", "0"), ("repulsion", "1"), ("temporary_particles", "1"),
                                  ("falloff_width", "0.05")) if row[k] != d]
        s = ", ".join(f"{k}={row[k]}" for k in changed) or "defaults"
        if row["density_tolerance_pct"] not in ("0.05",):
            s += f" tol {row['density_tolerance_pct']}/{row['divergence_tolerance_pct']}%"
    return s


# Linear panels show errors up to this many times the smallest; points
# beyond (runs that blew up) sit at the right edge with their value written.
LINEAR_CLIP = 4


def pareto_panel(ax, rows: list[dict], front_col: str, value_col: str, xlabel: str, transform, xscale: str) -> None:
    points = [r for r in rows if r["status"] == "ok" and r[front_col] != "n/a"]
    values = [max(transform(r[value_col]), 1e-6) for r in points]
    clip = LINEAR_CLIP * min(values) if values and xscale == "linear" else float("inf")
    for r, v in zip(points, values):
        style = GROUP_STYLE.get(r["group"], dict(marker="o"))
        color = METHOD_COLOR.get(r["method"], "gray")
        on = r[front_col] == "1"
        y = float(r["wall_s_per_sim_s"])
        if v > clip:
            ax.scatter(clip, y, marker=">", c="none", edgecolors=color, s=18, zorder=3)
            ax.annotate(f"{v:.2g}", (clip, y), fontsize=6, xytext=(-14, 3), textcoords="offset points")
            continue
        ax.scatter(v, y, s=36 if on else 18, c=color if on else "none", edgecolors=color, linewidths=1, zorder=3,
                   **style)
    # One front per resolution (the bench's front_* columns are per scene and
    # particle radius), drawn as a staircase: from each front point, what the
    # next costlier one buys.
    radii = sorted({r["particle_radius"] for r in points if r[front_col] == "1"}, key=float)
    for radius, ls in zip(radii, ["-", "--", ":", "-."] * 4):
        front = sorted((max(transform(r[value_col]), 1e-6), float(r["wall_s_per_sim_s"]), r)
                       for r in points if r[front_col] == "1" and r["particle_radius"] == radius)
        xs, ys = [], []
        for x, y, _ in sorted(front, key=lambda p: p[1]):
            if xs:
                xs.append(xs[-1])
                ys.append(y)
            xs.append(x)
            ys.append(y)
        ax.plot(xs, ys, color="black", lw=0.8, ls=ls, zorder=2, label=f"front, r = {radius} m")
        for x, y, r in front:
            text = label(r)
            if r["preset"] != "none":
                text = f"{r['preset']}: {text}"
            ax.annotate(text, (x, y), fontsize=6, xytext=(4, 2), textcoords="offset points",
                        fontweight="bold" if r["preset"] != "none" else "normal")
    if radii:
        ax.legend(fontsize=6, loc="upper right")
    ax.set_xscale(xscale)
    ax.set_yscale("log")
    if clip < float("inf"):
        ax.set_xlim(0, clip * 1.05)
    for axis, scale in ((ax.xaxis, xscale), (ax.yaxis, "log")):
        if scale != "log":
            continue
        axis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
        # Within one decade the minor ticks are the only labelled ones.
        lo, hi = (ax.get_xlim() if axis is ax.xaxis else ax.get_ylim())
        few = hi < 10 * lo
        axis.set_minor_formatter(matplotlib.ticker.FormatStrFormatter("%g") if few else matplotlib.ticker.NullFormatter())
    ax.set_xlabel(xlabel)
    ax.set_ylabel("wall s per simulated s")
    ax.grid(True, which="both", lw=0.3, alpha=0.5)


def legend_panel(ax, rows: list[dict]) -> None:
    ax.axis("off")
    handles = []
    for group, style in GROUP_STYLE.items():
        if any(r["group"] == group for r in rows):
            handles.append(plt.Line2D([], [], ls="", color="gray", label=group, **style))
    for method, color in METHOD_COLOR.items():
        handles.append(plt.Line2D([], [], ls="", marker="o", color=color, label=method))
    handles.append(plt.Line2D([], [], color="black", lw=0.8, label="Pareto front per resolution (filled: on it)"))
    ax.legend(handles=handles, loc="center", fontsize=8, frameon=False)
    loads = [float(r["load_avg"]) for r in rows]
    if loads:
        ax.text(0.5, 0.05, f"load average {min(loads):.1f}–{max(loads):.1f} (2 cores)", ha="center",
                transform=ax.transAxes, fontsize=7)


def plot_pareto(rows: list[dict], out: Path) -> None:
    fig, axes = plt.subplots(2, 3, figsize=(15, 9))
    for ax, panel in zip(axes.flat, PANELS):
        pareto_panel(ax, rows, *panel)
    legend_panel(axes.flat[-1], rows)
    fig.suptitle("flowclip bench accuracy: cost against error (2D dam break; control: 2D rectangular drop)")
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)


def read_martin_moyce(path: Path) -> tuple[list[float], list[float]]:
    T, Z = [], []
    with path.open() as f:
        lines = [line for line in f if line.strip() and not line.startswith("#")]
    for line in lines[1:]:
        t, z = line.split(",")
        T.append(float(t))
        Z.append(float(z))
    return T, Z


def plot_surge(rows: list[dict], fronts: list[dict], mm: tuple[list[float], list[float]] | None, out: Path) -> None:
    curves: dict[str, tuple[list[float], list[float]]] = {}
    for f in fronts:
        T, Z = curves.setdefault(f["id"], ([], []))
        T.append(float(f["T"]))
        Z.append(float(f["Z"]))
    fig, ax = plt.subplots(figsize=(7, 5))
    shown = [r for r in rows if r["id"] in curves and (r["preset"] != "none" or r["group"] == "resolution")]
    for r in shown:
        T, Z = curves[r["id"]]
        name = f"{r['preset']}: " if r["preset"] != "none" else ""
        name += label(r) + ("" if r["group"] == "resolution" else f" r {r['particle_radius']}")
        name += f" (RMS {float(r['surge_front_rms']):.3f})"
        ax.plot(T, Z, lw=1, label=name)
    if mm:
        ax.plot(*mm, "ko", ms=4, label="Martin & Moyce 1952, n² = 2, a = 2.25 in")
    ax.set_xlabel("T = t √(2g/a)")
    ax.set_ylabel("Z = x / a")
    ax.set_xlim(0, 4)
    ax.set_ylim(1, 5)
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.legend(fontsize=7)
    ax.set_title("2D dam break: surge front")
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dir", type=Path)
    p.add_argument("--martin-moyce", type=Path)
    a = p.parse_args()
    rows = read_rows(a.dir / "accuracy.csv")
    if not rows:
        raise SystemExit(f"{a.dir / 'accuracy.csv'}: no rows")
    plot_pareto(rows, a.dir / "pareto.svg")
    fronts = read_rows(a.dir / "surge_fronts.csv")
    plot_surge(rows, fronts, read_martin_moyce(a.martin_moyce) if a.martin_moyce else None, a.dir / "surge_front.svg")
    print(f"plots: {a.dir / 'pareto.svg'}, {a.dir / 'surge_front.svg'}")


if __name__ == "__main__":
    main()
