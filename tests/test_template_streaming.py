"""A template larger than `--template-memory` is streamed from its file
(docs/templates.md, "Templates larger than memory"): the run says so in its
summary, keeps no more of it than the budget, and the liquid it steers moves
exactly as with the template read whole."""
import json
import subprocess

import h5py
import numpy as np

from repo_paths import FLOWCLIP_BIN, ROOT

SCENE = ROOT / "scenes" / "drop2d.json"
FRAMES = 30  # the drop's instance starts at 0.2 s: 18 frames of control


def run(tmp_path, name, *extra):
    export, stats = tmp_path / f"{name}.h5", tmp_path / f"{name}.json"
    proc = subprocess.run([str(FLOWCLIP_BIN), "run", str(SCENE), "--frames", str(FRAMES), "--threads", "2",
                           "--templates", str(ROOT / "templates"), "--export", str(export), "--stats", str(stats),
                           *extra], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    with h5py.File(export, "r") as f:
        a, b = f["frames/offset"][-2], f["frames/offset"][-1]
        last = {k: f[f"particles/{k}"][a:b] for k in ("id", "position", "velocity")}
    return proc.stderr, json.loads(stats.read_text())["summary"], last


def test_a_streamed_template_steers_the_liquid_exactly_as_one_read_whole(tmp_path):
    _, whole, expected = run(tmp_path, "whole")
    err, streamed, got = run(tmp_path, "streamed", "--template-memory", "1")
    assert "templates_streamed" not in whole
    [t] = streamed["templates_streamed"]
    assert t["name"] == "drop2d" and t["cache_mb"] == 1
    assert t["frames_read"] >= 18, t
    assert t["peak_mb"] <= 1.5, t  # the budget and the frame in hand
    assert "template drop2d streamed from its file" in err
    np.testing.assert_array_equal(got["id"], expected["id"])
    np.testing.assert_array_equal(got["position"], expected["position"])
    np.testing.assert_array_equal(got["velocity"], expected["velocity"])


def test_a_budget_out_of_range_is_refused(tmp_path):
    proc = subprocess.run([str(FLOWCLIP_BIN), "run", str(SCENE), "--frames", "1", "--template-memory", "0"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "--template-memory" in proc.stderr
