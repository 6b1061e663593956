"""Smoke test of the edit-and-see benchmark (tools/bench_cache.py, `make bench-cache`): its quick
run writes a report whose figures are all there, finite and positive, in which every edit
re-simulates from the checkpoint just before its first changed frame (dense checkpoints, the
default) or from the every-K one before it (sparse), and the late edit re-simulates fewer frames
with checkpoints than without (it restarts from a later frame)."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

from repo_paths import FLOWCLIP_BIN, ROOT

SCENES = ("drop2d", "pool3d")


def positive(value) -> bool:
    return isinstance(value, (int, float)) and math.isfinite(value) and value > 0


# A benchmark of the Release build, left out of the sanitized run (heavy): there its 3D recording
# alone would take many minutes and its figures would mean nothing.
@pytest.mark.heavy
def test_quick_benchmark_report(tmp_path):
    assert FLOWCLIP_BIN.exists(), f"{FLOWCLIP_BIN} is missing: build first (make build) or set FLOWCLIP_BIN"
    run = subprocess.run([sys.executable, str(ROOT / "tools" / "bench_cache.py"), "--quick", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert "first updated frame" in run.stdout, "no progress lines"

    report = json.loads((tmp_path / "cache.json").read_text())
    markdown = (tmp_path / "cache.md").read_text()
    for key in ("machine", "date", "command", "settings", "scenes", "targets_met", "run_s"):
        assert key in report, key
    assert report["machine"]["cores"] >= 1 and report["machine"]["cpu"]
    assert "--quick" in report["command"] and report["command"] in markdown
    assert isinstance(report["targets_met"], bool)
    assert set(report["scenes"]) == set(SCENES)
    every = report["settings"]["checkpoint_every"]
    frames = report["settings"]["frames"]

    for key in SCENES:
        scene = report["scenes"][key]
        assert key in markdown
        assert scene["scene"]["dimension"] == (3 if key.endswith("3d") else 2)
        assert positive(scene["mean_frame_ms"])
        for kind, count in (("checkpoints", frames), ("sparse_checkpoints", frames // every)):
            ck = scene[kind]
            for figure in ("stored_bytes", "raw_bytes", "stored_bytes_per_particle", "raw_bytes_per_particle",
                           "fluid_particles_mean", "compression_ratio"):
                assert positive(ck[figure]), (key, kind, figure, ck[figure])
            assert ck["raw_bytes"] >= ck["stored_bytes"]
            assert ck["count"] == count, (key, kind, ck["frames"])
            assert positive(ck["save_ms"]["median"]) and positive(ck["restore_ms"]["median"])

        assert [e["label"] for e in scene["edits"]] == ["start", "middle", "end"]
        for e in scene["edits"]:
            assert 0 <= e["edit_frame"] <= frames
            for mode in ("checkpoints", "sparse", "no_checkpoints"):
                m = e[mode]
                for figure in ("first_updated_frame_ms", "done_ms"):
                    assert positive(m[figure]["median"]), (key, e["label"], mode, figure)
                assert m["first_updated_frame_ms"]["median"] <= m["done_ms"]["median"]
                assert m["to"] == frames and 0 <= m["from"] < max(e["edit_frame"], 1)
                assert m["frames_simulated"] == m["to"] - m["from"] > 0
            assert e["no_checkpoints"]["from"] == 0, "without checkpoints every edit re-simulates from frame 0"
            assert e["checkpoints"]["from"] == max(e["edit_frame"] - 1, 0), \
                "with dense checkpoints the re-simulation restarts from the frame before the first changed one"
            assert e["sparse"]["from"] == (e["edit_frame"] - 1) // every * every, \
                "the re-simulation restarts from the newest checkpoint before the first changed frame"

        # The late edit: checkpoints make it re-simulate fewer frames than a run from frame 0.
        late = scene["edits"][-1]
        assert late["checkpoints"]["from"] > late["no_checkpoints"]["from"] == 0
        assert late["checkpoints"]["frames_simulated"] < late["no_checkpoints"]["frames_simulated"]
        target = scene["targets"]["late_edit"]
        assert target["frames_met"], target
        assert isinstance(scene["targets"]["first_frame"]["met"], bool)

    # The 3D scene's template was recorded from the coarse dam break during the run.
    tpl = report["scenes"]["pool3d"]["template"]
    assert tpl["frames"] > 0 and positive(tpl["avg_particles"])
