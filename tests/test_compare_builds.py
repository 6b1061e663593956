"""tools/compare_builds.py with the same executable as old and new on a short 2D dam
break: both do the same work (deterministic solver), the report gives every run, the
medians and their ratio, and its markdown row carries the JSON's figures."""
from __future__ import annotations

import json
import statistics
import subprocess
import sys

import pytest

from repo_paths import FLOWCLIP_BIN, ROOT

SCENE = "scenes/bench/dambreak2d_r010.json"


def test_same_build_twice_does_the_same_work_and_is_reported(tmp_path):
    out = tmp_path / "report"
    cmd = [sys.executable, str(ROOT / "tools" / "compare_builds.py"), "--old", str(FLOWCLIP_BIN), "--new",
           str(FLOWCLIP_BIN), f"{SCENE}:3", "--repeat", "2", "--threads", "1", "--out", str(out), "--old-label", "build A",
           "--new-label", "build B"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "same work: yes" in done.stdout
    assert sorted(p.name for p in out.iterdir()) == ["compare.json", "compare.md"]
    report = json.loads((out / "compare.json").read_text())
    md = (out / "compare.md").read_text()
    assert report["benchmark"] == "compare_builds" and report["machine"]["cores"] >= 1
    assert report["command"] in md and "--repeat 2" in report["command"]
    assert report["old_label"] == "build A" and "old: build A (`" in md and "new: build B (`" in md
    (c,) = report["scenes"]
    assert c["scene"] == SCENE and c["frames"] == 3 and c["particles"] == 74 * 74
    assert c["same_work"] is True
    for w in ("old", "new"):
        runs = c["runs"][w]
        assert len(runs) == 2 and all(r["us"] > 0 and r["substeps"] >= 3 for r in runs)
        assert c[w]["us_median"] == pytest.approx(statistics.median(r["us"] for r in runs))
        assert c[w]["us_min"] <= c[w]["us_median"] <= c[w]["us_max"]
    assert c["new_over_old"] == pytest.approx(c["new"]["us_median"] / c["old"]["us_median"])
    row = next(line for line in md.splitlines() if line.startswith("| `dambreak2d_r010.json`, 3 frames |"))
    assert f"| {c['new_over_old']:.2f} |" in row and f"{c['new']['substeps']} substeps" in row


def test_a_missing_executable_is_refused(tmp_path):
    cmd = [sys.executable, str(ROOT / "tools" / "compare_builds.py"), "--old", str(tmp_path / "none"), "--new",
           str(FLOWCLIP_BIN), SCENE]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert done.returncode != 0 and "is not an executable" in done.stderr
