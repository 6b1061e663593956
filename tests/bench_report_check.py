"""What every report of `flowclip bench solver | control | scenes | service` carries
(server/bench/report.h), checked the same way for each: NAME.md and NAME.json alone in the
folder, the JSON's date, command, build and machine, and the markdown saying the same."""

from __future__ import annotations

import json
import math
import subprocess
from datetime import datetime
from pathlib import Path

from repo_paths import FLOWCLIP_BIN, ROOT


def run_bench(args: list[str], out: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    """`flowclip bench ARGS --out OUT` from the repository's root; it must exit 0."""
    cmd = [str(FLOWCLIP_BIN), "bench", *args, "--out", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    assert done.returncode == 0, f"{' '.join(cmd)} exited with {done.returncode}:\n{done.stdout}\n{done.stderr}"
    return done


def read_report(out: Path, name: str) -> tuple[dict, str]:
    """The report of `flowclip bench NAME` in OUT, its header checked: (JSON, markdown)."""
    # Staged under hidden names, then renamed: nothing else is left.
    assert sorted(p.name for p in out.iterdir()) == [f"{name}.json", f"{name}.md"]
    report = json.loads((out / f"{name}.json").read_text())
    md = (out / f"{name}.md").read_text()

    assert report["benchmark"] == name
    datetime.strptime(report["date"], "%Y-%m-%dT%H:%M:%SZ")  # ISO 8601, UTC
    words = report["command"].split()
    assert Path(words[0]).name == "flowclip" and words[1:3] == ["bench", name]
    assert words[words.index("--out") + 1] == str(out)
    assert report["duration_s"] > 0

    version = subprocess.run([str(FLOWCLIP_BIN), "--version"], capture_output=True, text=True, timeout=30)
    build = report["flowclip"]
    assert build["version"] == version.stdout.strip()
    assert build["real"] in ("float", "double")
    assert build["compiler"] and build["build_type"] and build["build_flags"]

    machine = report["machine"]
    assert machine["cpu"] and machine["os"] and machine["kernel"].startswith("Linux ")
    assert machine["cores"] >= 1 and machine["threads"] >= 1
    for key in ("loadavg_at_start", "loadavg_at_end"):
        assert len(machine[key]) == 3 and all(load >= 0 for load in machine[key]), key

    # The markdown's header says the same.
    assert md.startswith("# ")
    assert f"\n- date: {report['date']}\n" in md
    assert f"\n- command: `{report['command']}`\n" in md
    assert f"\n- flowclip {build['version']}, {build['build_type']} build ({build['compiler']}, " in md
    assert f"Real = {build['real']}\n" in md
    assert (f"\n- machine: {machine['cpu']}, {machine['cores']} cores, {machine['threads']} OpenMP thread"
            in md)
    loads = [" ".join(f"{load:.2f}" for load in machine[key]) for key in ("loadavg_at_start", "loadavg_at_end")]
    assert f"{loads[0]} at the start, {loads[1]} at the end" in md
    return report, md


def md_row(*cells) -> str:
    """A markdown table row as the reports write it."""
    return "| " + " | ".join(str(c) for c in cells) + " |\n"


def lattice_particles(lo, hi, radius: float) -> int:
    """Particles of a block sampled at spacing 2r, as server/sph/sampling/lattice.h counts them."""
    return math.prod(max(0, math.floor((h - l) / (2 * radius) + 1e-4)) for l, h in zip(lo, hi))


def block_particles(scene_file: Path) -> int:
    """Liquid particles of a scene's fluid blocks."""
    scene = json.loads(scene_file.read_text())
    return sum(lattice_particles(b["min"], b["max"], scene["particle_radius"]) for b in scene["fluid_blocks"])
