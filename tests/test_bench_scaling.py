"""tools/bench_scaling.py at its smallest: the 3D dam break at two particle
counts, each run at the radius that puts n³ particles in its block, and a
report (scaling.md + scaling.json) whose rows say what the JSON says."""
from __future__ import annotations

import json
import subprocess
import sys

from bench_report_check import md_row
from repo_paths import ROOT


def test_scaling_report(tmp_path):
    out = tmp_path / "scaling"
    cmd = [sys.executable, str(ROOT / "tools" / "bench_scaling.py"), "--counts", "8k,1k", "--seconds", "0.05",
           "--threads", "1", "--repeat", "2", "--out", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in out.iterdir()) == ["scaling.json", "scaling.md"]
    report = json.loads((out / "scaling.json").read_text())
    md = (out / "scaling.md").read_text()
    assert report["command"].startswith("tools/bench_scaling.py") and report["machine"]["cores"] >= 1
    runs = report["runs"]
    # Smallest first; the block holds exactly n³ particles at the chosen radius.
    assert [r["liquid_particles"] for r in runs] == [10 ** 3, 20 ** 3]
    assert runs[0]["particle_radius"] == 2 * runs[1]["particle_radius"]
    for r in runs:
        assert r["frames"] == 3 and r["unconverged_frames"] == 0
        assert r["us_per_particle_step"] > 0 and r["substeps_per_frame"] >= 1
        assert r["bytes_per_liquid_particle"] == r["peak_rss_mb"] * 1e6 / r["liquid_particles"]
        assert md_row(f"{r['liquid_particles']:,}", f"{1000 * r['particle_radius']:.3f}",
                      f"{r['substeps_per_frame']:.1f}", f"{r['solver_iterations_per_substep']:.1f}",
                      f"{r['us_per_particle_step']:.3f}",
                      f"{r['us_per_particle_step'] / runs[0]['us_per_particle_step']:.2f}",
                      f"{r['ms_per_frame']:.0f}", f"{r['peak_rss_mb']:.0f}",
                      f"{r['bytes_per_liquid_particle']:.0f}",
                      ", ".join(f"{u:.3f}" for u in r["us_per_particle_step_runs"])) in md
        # Each row is its size's fastest of the rounds.
        assert len(r["us_per_particle_step_runs"]) == 2 and r["us_per_particle_step"] == min(r["us_per_particle_step_runs"])
    # The memory parts: the liquid's own arrays (position, velocity, acceleration: 3 floats each; mass,
    # density, pressure and its average; phase, kind, id) and a list entry and a pair term per neighbour pair.
    for r in runs:
        mem, n = r["memory_bytes"], r["liquid_particles"]
        assert 58 * n <= mem["liquid_particles"] <= 2 * 58 * n
        assert mem["pair_terms"] >= 4 * n and mem["neighbour_lists"] >= mem["pair_terms"] + 4 * (n + 1)
        assert mem["boundary_samples"] >= 28 * r["boundary_particles"]
        assert mem["boundary_model"] == 0  # the scene's wall samples need no map
        parts = ("liquid_particles", "neighbour_lists", "pair_terms", "neighbour_grids", "boundary_sums",
                 "boundary_samples", "boundary_model")
        assert mem["counted"] == sum(mem[k] for k in parts) < r["peak_rss_mb"] * 1e6
        assert md_row(f"{n:,}", *(f"{mem[k] / n:.0f}" for k in parts), f"{mem['counted'] / n:.0f}",
                      f"{(r['peak_rss_mb'] * 1e6 - mem['counted']) / n:.0f}") in md
