#!/usr/bin/env python3
"""What running FlowClip's independent work on a Dask cluster costs and gains (docs/batch.md,
"What it costs"), on one machine with a LocalCluster of --workers worker processes:

  accuracy sweep   `flowclip bench accuracy --quick --threads 1` one point after the other against
                   the same with `--local W` (the points as tasks, one OpenMP thread each): the
                   command's wall time, the points' own wall time (the sum of their children's),
                   and the runner's overhead per task (below); the figures of both CSVs are
                   checked equal where they do not depend on timing
  frame export     `flowclip export FRAMES.h5 --formats ply` with --threads 1 and --threads W
                   against `flowclip-batch export ... --local W` on the same particle export (a 3D
                   dam break of --export-seconds): wall time, speed-up over one thread, and
                   whether the files are byte for byte the same

Overhead per task = (W x T_batch - S) / N: the worker-seconds the batch held (W workers for the
T_batch seconds `flowclip-batch commands` ran, from its start to its summary line) minus those
spent inside the N points' own children (S), per task: cluster start and stop, scheduling,
staging folders, and the last tasks' wait while a worker idles. The fixed part is measured apart:
a list of W `true` commands through the same runner (T_fixed), so the marginal cost per task is
(W x (T_batch - T_fixed) - S) / N.

Each configuration runs --repeat times, alternating, so that a change in the machine's load hits
all alike; the report gives the median and the range. Writes OUT/batch.md and OUT/batch.json.
Usage: tools/bench_batch.py [--out bench/batch] [--repeat 3] [--workers 2] (`make bench-batch`).
"""

from __future__ import annotations

import argparse
import csv
import filecmp
import json
import os
import re
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_report import report_start, write_report  # tools/, beside this script

ROOT = Path(__file__).resolve().parent.parent
FLOWCLIP_BIN = Path(os.environ.get("FLOWCLIP_BIN", ROOT / "build" / "flowclip")).resolve()
BATCH = Path(sys.executable).parent / "flowclip-batch"  # the package of the Python running this script
TIMEOUT_S = 3600  # generous: a loaded machine is slow, never a hang
# Figures of accuracy.csv that depend on the time a run took, not on what it simulated.
TIMING = {"wall_s_per_sim_s", "ms_per_frame", "us_per_particle_step", "cpu_s_per_sim_s", "load_avg", "preset",
          "front_avg_density_error", "front_max_density_error", "front_volume_drift", "front_surge_front_rms",
          "front_fidelity"}
POINT_WALL = re.compile(r"^\[\d+/\d+\] .*?: ([0-9.]+) s wall,")


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def spread(values) -> dict:
    return {"median": statistics.median(values), "min": min(values), "max": max(values),
            "samples": [round(v, 3) for v in values]}


def timed(cmd, **kw) -> tuple[float, list[tuple[float, str]]]:
    """Runs cmd; its wall time and its stderr lines, each with the time it arrived (from the start)."""
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT, **kw)
    lines = [(time.monotonic() - t0, line.rstrip("\n")) for line in proc.stderr]
    code = proc.wait(timeout=TIMEOUT_S)
    wall = time.monotonic() - t0
    if code != 0:
        raise SystemExit(f"{shlex.join(map(str, cmd))} exited with {code}:\n" + "\n".join(l for _, l in lines[-30:]))
    return wall, lines


def csv_rows(path: Path) -> list[dict]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def accuracy_sweep(tmp: Path, workers: int, repeat: int, templates: Path) -> dict:
    env = {**os.environ, "FLOWCLIP_BATCH": str(BATCH)}
    base = [str(FLOWCLIP_BIN), "bench", "accuracy", "--quick", "--threads", "1", "--no-plots",
            "--templates", str(templates)]
    trivial = tmp / "trivial.json"
    trivial.write_text(json.dumps([{"argv": ["/bin/true"], "cwd": f"trivial/{i}"} for i in range(workers)]))
    seq, dask, fixed = [], [], []
    figures_equal = True
    for k in range(repeat):
        out_seq, out_dask = tmp / f"seq{k}", tmp / f"dask{k}"
        log(f"accuracy sweep {k + 1}/{repeat}: sequential")
        wall, lines = timed(base + ["--out", str(out_seq)], env=env)
        points = [float(m.group(1)) for _, l in lines if (m := POINT_WALL.match(l))]
        seq.append({"wall_s": wall, "points": len(points), "points_wall_s": sum(points)})
        log(f"accuracy sweep {k + 1}/{repeat}: --local {workers}")
        wall, lines = timed(base + ["--out", str(out_dask), "--local", str(workers)], env=env)
        points = [float(m.group(1)) for _, l in lines if (m := POINT_WALL.match(l))]
        start = next(t for t, l in lines if l.startswith("bench accuracy: ") and " as tasks of " in l)
        end = next(t for t, l in lines if l.startswith("flowclip-batch: "))
        dask.append({"wall_s": wall, "batch_s": end - start, "points": len(points), "points_wall_s": sum(points)})
        log(f"accuracy sweep {k + 1}/{repeat}: the runner's fixed cost ({workers} `true` commands)")
        shutil.rmtree(tmp / "trivial", ignore_errors=True)
        wall, _ = timed([str(BATCH), "commands", str(trivial), "--local", str(workers)])
        fixed.append(wall)
        a, b = csv_rows(out_seq / "accuracy.csv"), csv_rows(out_dask / "accuracy.csv")
        figures_equal = figures_equal and len(a) == len(b) and all(
            x[c] == y[c] for x, y in zip(a, b) for c in x if c not in TIMING)
    n = dask[0]["points"]
    per_task = [(workers * d["batch_s"] - d["points_wall_s"]) / n for d in dask]
    marginal = [(workers * (d["batch_s"] - f) - d["points_wall_s"]) / n for d, f in zip(dask, fixed)]
    seq_wall = spread([s["wall_s"] for s in seq])
    dask_wall = spread([d["wall_s"] for d in dask])
    return {"points": n, "workers": workers, "threads_per_point": 1,
            "sequential": {"wall_s": seq_wall, "points_wall_s": spread([s["points_wall_s"] for s in seq])},
            "dask": {"wall_s": dask_wall, "batch_s": spread([d["batch_s"] for d in dask]),
                     "points_wall_s": spread([d["points_wall_s"] for d in dask])},
            "fixed_s": spread(fixed),
            "overhead_per_task_s": spread(per_task), "marginal_overhead_per_task_s": spread(marginal),
            "speedup": seq_wall["median"] / dask_wall["median"], "figures_equal": figures_equal,
            "command_sequential": shlex.join(["flowclip"] + base[1:] + ["--out", "DIR"]),
            "command_dask": shlex.join(["flowclip"] + base[1:] + ["--out", "DIR", "--local", str(workers)])}


def frame_export(tmp: Path, workers: int, repeat: int, seconds: float) -> dict:
    frames = tmp / "dambreak3d.h5"
    log(f"frame export: a particle export of scenes/dambreak3d.json, {seconds} s")
    subprocess.run([str(FLOWCLIP_BIN), "run", str(ROOT / "scenes" / "dambreak3d.json"), "--seconds", str(seconds),
                    "--export", str(frames), "--quiet"], check=True, timeout=TIMEOUT_S, cwd=ROOT)
    import h5py

    with h5py.File(frames, "r") as f:
        count = len(f["frames/index"])
    configs = {
        "flowclip export --threads 1": [str(FLOWCLIP_BIN), "export", str(frames), "--formats", "ply", "--threads", "1",
                                        "--quiet", "--out"],
        f"flowclip export --threads {workers}": [str(FLOWCLIP_BIN), "export", str(frames), "--formats", "ply",
                                                 "--threads", str(workers), "--quiet", "--out"],
        f"flowclip-batch export --local {workers}": [str(BATCH), "export", str(frames), "--formats", "ply", "--local",
                                                     str(workers), "--binary", str(FLOWCLIP_BIN), "--out"],
    }
    walls = {name: [] for name in configs}
    outs = {}
    for k in range(repeat):
        for n, (name, cmd) in enumerate(configs.items()):
            out = tmp / f"export{n}"
            shutil.rmtree(out, ignore_errors=True)
            log(f"frame export {k + 1}/{repeat}: {name}")
            wall, _ = timed(cmd + [str(out)])
            walls[name].append(wall)
            outs[name] = out
    # The same files from all three (the manifests aside: they name their own command).
    reference = outs[next(iter(configs))]
    names = sorted(p.name for p in reference.iterdir() if not p.name.endswith(".export.json"))
    identical = all(sorted(p.name for p in out.iterdir() if not p.name.endswith(".export.json")) == names and
                    all(filecmp.cmp(reference / f, out / f, shallow=False) for f in names) for out in outs.values())
    one = statistics.median(walls[next(iter(configs))])
    return {"frames": count, "seconds": seconds, "workers": workers, "files": len(names),
            "bytes": sum((reference / f).stat().st_size for f in names), "identical_files": identical,
            "runs": {name: {**spread(w), "speedup": one / statistics.median(w)} for name, w in walls.items()}}


def fmt_s(s: dict) -> str:
    return f"{s['median']:.2f} s" + (f" ({s['min']:.2f}–{s['max']:.2f})" if len(s["samples"]) > 1 else "")


def markdown(report: dict) -> str:
    m, acc, exp = report["machine"], report["accuracy"], report["export"]
    w = acc["workers"]
    lines = [
        "# Batch runs on a Dask cluster: what it costs",
        "",
        f"Measured {report['date']} on {m['cpu']} ({m['cores']} cores; load average {m['loadavg_at_start']} at the "
        f"start, {report['loadavg_at_end']} at the end; niceness {m['niceness']}), a Dask LocalCluster of {w} worker "
        f"processes on the same machine. {report['repeat']} run(s) of each configuration, alternating: the median, "
        "with the range.",
        "",
        "```sh",
        report["command"],
        "```",
        "",
        f"## The accuracy sweep (`--quick`), {acc['points']} points",
        "",
        f"`{acc['command_sequential']}` against `{acc['command_dask']}`: the quick sweep (coarse, short points of "
        "a few tenths of a second each), one OpenMP thread per point in both. The points' own wall time is the sum "
        "of their `flowclip run` children's.",
        "",
        "| | wall time | points' own wall time (sum) | runner (`flowclip-batch commands`) |",
        "|---|---:|---:|---:|",
        f"| one after the other | {fmt_s(acc['sequential']['wall_s'])} | {fmt_s(acc['sequential']['points_wall_s'])} "
        "| |",
        f"| `--local {w}` | {fmt_s(acc['dask']['wall_s'])} | {fmt_s(acc['dask']['points_wall_s'])} | "
        f"{fmt_s(acc['dask']['batch_s'])} |",
        "",
        f"- speed-up of the sweep: **{acc['speedup']:.2f}×** on {w} workers",
        f"- the points' own wall time, {w} at once against one at a time: "
        f"{acc['dask']['points_wall_s']['median'] / acc['sequential']['points_wall_s']['median']:.2f}× "
        "(above 1 where the runs side by side slow each other down: cores shared with other processes, memory)",
        f"- fixed cost of the runner ({w} `true` commands: LocalCluster start and stop): {fmt_s(acc['fixed_s'])}",
        f"- overhead per task, (W × T_batch − S) / N: {fmt_s(acc['overhead_per_task_s'])}; without the fixed cost, "
        f"(W × (T_batch − T_fixed) − S) / N: {fmt_s(acc['marginal_overhead_per_task_s'])}",
        f"- the CSVs' figures that do not depend on timing are {'equal' if acc['figures_equal'] else '**not** equal'}"
        " point by point",
        "",
        "W: workers; T_batch: from the runner's start to its summary line; S: the points' own wall time; N: tasks. "
        "The overhead counts the worker-seconds the batch held but did not spend inside a point: cluster start and "
        "stop, scheduling, staging folders, and a worker idle while the last task runs. A marginal figure near "
        "zero or below it is within the run-to-run spread of the fixed cost.",
        "",
        f"## Frame-parallel export, {exp['frames']} frames of a 3D dam break to PLY",
        "",
        f"A particle export of `scenes/dambreak3d.json` ({exp['seconds']} s simulated), meshed into {exp['files']} "
        f"PLY files ({exp['bytes'] / 1e6:.1f} MB); the files of the three are "
        f"{'byte for byte the same' if exp['identical_files'] else '**not** the same'}.",
        "",
        "| command | wall time | speed-up over one thread |",
        "|---|---:|---:|",
    ]
    for name, r in exp["runs"].items():
        lines.append(f"| `{name}` | {fmt_s(r)} | {r['speedup']:.2f}× |")
    lines += [
        "",
        "A run in parallel gains only the cores other processes leave free: read the figures against the load "
        "average above. On one machine `--threads` and `--local` share the same cores; a cluster's workers on "
        "other machines add theirs.",
        "",
    ]
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="bench/batch", help="report directory (batch.md, batch.json)")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each configuration (default 3)")
    ap.add_argument("--workers", type=int, default=2, help="LocalCluster worker processes (default 2)")
    ap.add_argument("--export-seconds", type=float, default=0.5, help="simulated seconds of the 3D export")
    a = ap.parse_args()
    if not FLOWCLIP_BIN.exists():
        raise SystemExit(f"{FLOWCLIP_BIN} is missing: build first (make build) or set FLOWCLIP_BIN")
    if not BATCH.exists():
        raise SystemExit(f"{BATCH} is missing: install the Python package with Dask (make setup)")
    templates = Path("templates")  # relative to ROOT, where the commands run
    if not (ROOT / templates / "drop2d.h5").exists():
        raise SystemExit("templates/drop2d.h5 is missing: make templates")
    report = report_start("tools/bench_batch.py", sys.argv[1:])
    report["repeat"] = a.repeat
    with tempfile.TemporaryDirectory(prefix="flowclip-bench-batch-") as tmp:
        report["accuracy"] = accuracy_sweep(Path(tmp), a.workers, a.repeat, templates)
        report["export"] = frame_export(Path(tmp), a.workers, a.repeat, a.export_seconds)
    write_report(Path(a.out), "batch", report, markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
