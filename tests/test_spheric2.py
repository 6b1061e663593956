"""tools/spheric2.py, SPHERIC Test 2 [KFV*05]: the experiment's gauge data as committed (four gauges, the
reservoir's full at the start, the others dry until the front comes), and a coarse, short run of
the scene through the script: a complete report, the reservoir's height at the start, and the
front reaching the gauge nearest the reservoir when the experiment's did."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from repo_paths import FLOWCLIP_BIN, ROOT

sys.path.insert(0, str(ROOT / "tools"))
import spheric2  # noqa: E402  (tools/ is not a package)


def test_the_gauge_data_is_the_experiments():
    exp = spheric2.read_gauges()
    assert list(exp) == ["t"] + list(spheric2.GAUGES)
    assert len(exp["t"]) > 500 and exp["t"][0] < 0.01 and exp["t"][-1] > 5.9
    assert np.all(np.diff(exp["t"]) > 0)
    # The reservoir gauge stands in 0.55 m of water; the others are dry until the front comes,
    # first at the gauge nearest the reservoir, last behind the box.
    assert exp["x2.638"][0] == pytest.approx(0.55, abs=0.01)
    arrivals = [spheric2.arrival(exp["t"], exp[g]) for g in ("x1.488", "x0.992", "x0.496")]
    assert all(a is not None for a in arrivals) and arrivals == sorted(arrivals), arrivals
    assert 0.1 < arrivals[0] < 0.3
    for name in ("x0.496", "x0.992", "x1.488"):
        assert exp[name][0] < 0.005, name


def test_a_gauge_reads_the_water_standing_on_the_floor_not_the_spray():
    r = 0.01
    column = np.array([0.05, 0.01, 0.03])  # three rows from the floor up, in any order
    assert spheric2.column_top(column, r) == pytest.approx(0.06)
    # A droplet more than two diameters above the column is spray; one within two is still water.
    assert spheric2.column_top(np.append(column, 0.2), r) == pytest.approx(0.06)
    assert spheric2.column_top(np.append(column, 0.085), r) == pytest.approx(0.095)
    # Nothing on the floor (a jet passing over the gauge) and nothing at all read dry.
    assert spheric2.column_top(np.array([0.2, 0.22]), r) == 0.0
    assert spheric2.column_top(np.array([]), r) == 0.0


@pytest.mark.heavy
def test_a_coarse_run_reaches_the_first_gauge_with_the_experiment(tmp_path):
    out = tmp_path / "report"
    cmd = [sys.executable, str(ROOT / "tools" / "spheric2.py"), "--radius", "0.0275", "--seconds", "0.5",
           "--threads", "1", "--out", str(out), "--binary", str(FLOWCLIP_BIN)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=1800, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert {p.name for p in out.iterdir()} == {"spheric2.md", "spheric2.json", "spheric2.svg"}
    report = json.loads((out / "spheric2.json").read_text())
    assert report["settings"]["particles"] == 3960 and report["machine"]["cores"] >= 1
    sim = report["simulated"]
    # 10 layers of 5.5 cm: the reservoir's top at 0.55 m, where the experiment's water stood.
    assert sim["x2.638"][0] == pytest.approx(0.55, abs=0.03)
    gauge = report["gauges"]["x1.488"]
    assert gauge["arrival_s"] is not None, "the front must reach the gauge 0.5 m from the reservoir within 0.5 s"
    assert abs(gauge["arrival_s"] - gauge["measured_arrival_s"]) < 0.08, gauge
    # Behind the box the front has not arrived by 0.5 s, in the experiment nor here.
    assert report["gauges"]["x0.496"]["arrival_s"] is None
    assert "| x = 1.488 m |" in (out / "spheric2.md").read_text()
