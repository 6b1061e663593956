"""`flowclip bench control --repeat N`: the control overhead of a noisy host
read as the median of N runs per mode, with the range, in the table, the
verdict and the JSON (README "Control overhead")."""
from __future__ import annotations

import json
import re
import subprocess

import pytest

from repo_paths import FLOWCLIP_BIN, ROOT

REPEAT = 3


def test_repeat_reports_the_median_run_and_the_range(template_dir, tmp_path):
    out = tmp_path / "control.json"
    done = subprocess.run([str(FLOWCLIP_BIN), "bench", "control", str(ROOT / "scenes" / "drop2d.json"), "--frames",
                           "16", "--threads", "1", "--repeat", str(REPEAT), "--templates", str(template_dir),
                           "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    # Every run is announced, the modes alternating.
    announced = re.findall(r"control forces (per frame \(paper\)|every substep) \(run (\d)/3\)", done.stderr)
    assert announced == [(mode, str(k)) for k in range(1, REPEAT + 1)
                         for mode in ("per frame (paper)", "every substep")]
    rows = json.loads(out.read_text())
    assert [r["control_setting"] for r in rows] == ["forces_every_substep=0", "forces_every_substep=1"]
    # Written under a temporary name, then renamed: nothing else is left.
    assert sorted(p.name for p in tmp_path.iterdir()) == ["control.json"]
    for row in rows:
        runs = row["control_pct_runs"]
        assert len(runs) == REPEAT and all(p > 0 for p in runs)
        # The reported run is the median one (the upper middle for an even count).
        assert row["control_pct"] == sorted(runs)[REPEAT // 2]
        assert row["control_pct"] == pytest.approx(100 * row["control_ms_per_frame"] / row["simulation_ms_per_frame"])
    verdict = next(line for line in done.stdout.splitlines() if line.startswith("drop2d: control is"))
    per_frame, substep = rows
    lo, hi = min(per_frame["control_pct_runs"]), max(per_frame["control_pct_runs"])
    assert f"control is {per_frame['control_pct']:.1f} % (median of 3 runs, {lo:.1f}-{hi:.1f} %)" in verdict
    lo, hi = min(substep["control_pct_runs"]), max(substep["control_pct_runs"])
    assert f"every substep: {substep['control_pct']:.1f} % (median of 3 runs, {lo:.1f}-{hi:.1f} %)" in verdict


def test_repeat_must_be_positive(template_dir):
    done = subprocess.run([str(FLOWCLIP_BIN), "bench", "control", str(ROOT / "scenes" / "drop2d.json"), "--repeat",
                           "0", "--templates", str(template_dir)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert "--repeat" in done.stdout + done.stderr
