"""`flowclip bench control --repeat N`: the control overhead of a noisy host
read as the median of N runs per mode, with the range, in the table, the
verdict and the report (control.md + control.json, README "Control overhead")."""
from __future__ import annotations

import re
import subprocess

import pytest

from bench_report_check import block_particles, md_row, read_report, run_bench
from repo_paths import FLOWCLIP_BIN, ROOT

REPEAT = 3
FRAMES = 16
DROP = ROOT / "scenes" / "drop2d.json"


@pytest.mark.heavy
def test_repeat_reports_the_median_run_and_the_range(template_dir, tmp_path):
    out = tmp_path / "control"
    done = run_bench(["control", str(DROP), "--frames", str(FRAMES), "--threads", "1", "--repeat", str(REPEAT),
                      "--templates", str(template_dir)], out)
    # Every run is announced, the modes alternating.
    announced = re.findall(r"control forces (per frame \(paper\)|every substep) \(run (\d)/3\)", done.stderr)
    assert announced == [(mode, str(k)) for k in range(1, REPEAT + 1)
                         for mode in ("per frame (paper)", "every substep")]
    report, md = read_report(out, "control")
    assert report["settings"]["repeat"] == REPEAT and report["machine"]["threads"] == 1
    rows = report["runs"]
    assert [r["control_setting"] for r in rows] == ["forces_every_substep=0", "forces_every_substep=1"]
    for row in rows:
        runs = row["control_pct_runs"]
        assert len(runs) == REPEAT and all(p > 0 for p in runs)
        # The reported run is the median one (the upper middle for an even count).
        assert row["control_pct"] == sorted(runs)[REPEAT // 2]
        assert row["control_pct"] == pytest.approx(100 * row["control_ms_per_frame"] / row["simulation_ms_per_frame"])
        # The drop's block, counted over the frames where its instance plays (from t = 0.2 s).
        assert row["frames"] == FRAMES and 1 <= row["active_frames"] < FRAMES
        assert row["liquid_particles"] == pytest.approx(block_particles(DROP), rel=0.01)
        assert row["control_particles"] > 0 and row["peak_rss_mb"] > 0
        assert row["template_storage_mb"] == pytest.approx((template_dir / "drop2d.h5").stat().st_size / 1e6)
        # The markdown's row says the same.
        mode = "per frame (paper)" if row["control_setting"].endswith("=0") else "every substep"
        assert (f"| drop2d | {mode} | {row['active_frames']}/{row['frames']} | "
                f"{row['liquid_particles'] / 1000:.1f}k | ") in md
        assert (f" | {row['simulation_ms_per_frame']:.1f} | {row['control_ms_per_frame']:.2f} | "
                f"{row['control_pct']:.1f}% | {row['peak_rss_mb']:.0f} MB | {row['template_storage_mb']:.2f} | "
                f"{'-' if row['fidelity'] < 0 else format(row['fidelity'], '.3f')} |\n") in md
    verdict = next(line for line in done.stdout.splitlines() if line.startswith("drop2d: control is"))
    per_frame, substep = rows
    lo, hi = min(per_frame["control_pct_runs"]), max(per_frame["control_pct_runs"])
    assert f"control is {per_frame['control_pct']:.1f} % (median of 3 runs, {lo:.1f}-{hi:.1f} %)" in verdict
    lo, hi = min(substep["control_pct_runs"]), max(substep["control_pct_runs"])
    assert f"every substep: {substep['control_pct']:.1f} % (median of 3 runs, {lo:.1f}-{hi:.1f} %)" in verdict
    assert report["verdicts"] == [verdict] and f"\n- {verdict}\n" in md
    # The paper's row beside ours.
    assert md_row("paper", "2D Rectangular drop", "-", "6.7k", "1.3k", "88", "36", "190.2", "5.6", "2.9%", "0.33 GB",
                  "3.87", "-") in md


def test_repeat_must_be_positive(template_dir):
    done = subprocess.run([str(FLOWCLIP_BIN), "bench", "control", str(DROP), "--repeat",
                           "0", "--templates", str(template_dir)], capture_output=True, text=True, timeout=900)
    assert done.returncode == 2
    assert "--repeat" in done.stdout + done.stderr
