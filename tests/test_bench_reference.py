"""tools/bench_reference.py without SPlisHSPlasH itself: the reference scenes
it writes carry our bench scenes' settings, a SPlisHSPlasH run's printed
summary becomes its figures, and the report divides them pair by pair."""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
import bench_reference  # noqa: E402  (tools/)

from repo_paths import FLOWCLIP_BIN  # noqa: E402  (tests/, beside this file)

# The shape of SPlisHSPlasH's shipped dam breaks, with values unlike ours so
# that a setting not carried over shows.
SHIPPED = {
    "Configuration": {
        "particleRadius": 0.025, "sim2D": True, "pause": True, "gravitation": [0, -1, 0],
        "cflMethod": 2, "cflFactor": 0.5, "cflMaxTimeStepSize": 0.01, "boundaryHandlingMethod": 2,
        "DFSPH": {"minIterations": 2, "maxIterations": 100, "maxError": 0.5, "maxIterationsV": 100,
                  "maxErrorV": 0.7, "enableDivergenceSolver": False},
    },
    "Materials": [{"id": "Fluid", "density0": 500, "viscosityMethod": 3, "vorticityMethod": 1,
                   "Standard viscosity": {"viscosity": 0.5}}],
    "RigidBodies": [{"geometryFile": "../models/UnitBox.obj", "scale": [4, 4, 1], "isWall": True}],
    "FluidBlocks": [{"start": [-2.0, 0.0, -1], "end": [-0.5, 1.5, 1]}],
}


@pytest.mark.parametrize("name", sorted(bench_reference.SCENES))
def test_reference_scene_carries_our_settings(name):
    ours_path, shipped_name, radius = bench_reference.SCENES[name]
    ours = bench_reference.our_scene(name)
    assert ours["particle_radius"] == (radius or json.loads((ROOT / ours_path).read_text())["particle_radius"])
    shipped = json.loads(json.dumps(SHIPPED))
    s = bench_reference.reference_scene(ours, shipped)
    c = s["Configuration"]
    assert c["particleRadius"] == ours["particle_radius"]
    assert c["DFSPH"]["maxError"] == ours["solver"]["density_tolerance_pct"]
    assert c["DFSPH"]["maxErrorV"] == ours["solver"]["divergence_tolerance_pct"]
    assert c["DFSPH"]["enableDivergenceSolver"] is True
    assert c["cflMethod"] == 1
    assert c["cflFactor"] == ours["settings"]["cfl_factor"]
    assert c["cflMaxTimeStepSize"] == ours["settings"]["dt_max"]
    assert c["pause"] is False
    assert c["gravitation"][:ours["dimension"]] == ours["gravity"]
    (m,) = s["Materials"]
    (phase,) = ours["phases"]
    assert m["density0"] == phase["rest_density"]
    assert m["viscosityMethod"] == 1 and m["Standard viscosity"]["viscosity"] == phase["viscosity"]
    assert "vorticityMethod" not in m
    # Its tank and block stay its own; the shipped dict is not modified.
    assert s["RigidBodies"] == SHIPPED["RigidBodies"] and s["FluidBlocks"] == SHIPPED["FluidBlocks"]
    assert shipped == SHIPPED
    # 3D scenes come from the 3D dam break, 2D from the 2D one.
    assert shipped_name == ("DamBreakModel_2D.json" if ours["dimension"] == 2 else "DamBreakModel.json")


# The tank and block of SPlisHSPlasH 2.19's DamBreakModel.json and DamBreakModel_2D.json.
SHIPPED_TANKS = {
    3: {"RigidBodies": [{"translation": [0, 1.5, 0], "scale": [4, 3, 1.5], "isWall": True}],
        "FluidBlocks": [{"start": [-0.5, 0.0, -0.5], "end": [0.5, 1.0, 0.5], "translation": [-1.45, 0.05, 0.0],
                         "scale": [1, 1, 1]}]},
    2: {"RigidBodies": [{"translation": [0, 2.0, 0], "scale": [4, 4, 1], "isWall": True}],
        "FluidBlocks": [{"start": [-2.0, 0.0, -1], "end": [-0.5, 1.5, 1], "translation": [0.025, 0.025, 0.0],
                         "scale": [1, 1, 1]}]},
}


@pytest.mark.parametrize("name", sorted(bench_reference.SCENES))
def test_our_block_stands_particle_on_particle_where_its_block_does(name):
    ours = bench_reference.our_scene(name)
    shipped = SHIPPED_TANKS[ours["dimension"]]
    moved = bench_reference.at_reference_block(ours, shipped)
    assert ours == bench_reference.our_scene(name), "the caller's scene is not modified"
    r, dim = ours["particle_radius"], ours["dimension"]
    (theirs,) = shipped["FluidBlocks"]
    (block,) = moved["fluid_blocks"]
    (tank,) = shipped["RigidBodies"]
    tank_min = [t - k / 2 for t, k in zip(tank["translation"], tank["scale"])]
    for d in range(dim):
        # Its sampling rule (SimulatorBase::createFluidBlocks) and ours, from each one's lower corner.
        lo, hi = (theirs[k][d] + theirs["translation"][d] for k in ("start", "end"))
        steps = round((hi - lo) / (2 * r)) - 1
        its = [lo + 2 * r + 2 * r * j - tank_min[d] for j in range(steps)]
        mine = [block["min"][d] + r + 2 * r * i - moved["domain"]["min"][d]
                for i in range(round((block["max"][d] - block["min"][d]) / (2 * r)))]
        assert mine == pytest.approx(its, abs=1e-9), d
        assert moved["domain"]["min"][d] < block["min"][d] < block["max"][d] < moved["domain"]["max"][d]
    # A block that would leave our domain is refused.
    far = json.loads(json.dumps(shipped))
    far["FluidBlocks"][0]["translation"][0] += 10
    with pytest.raises(ValueError, match="outside"):
        bench_reference.at_reference_block(ours, far)
    assert {k: v for k, v in moved.items() if k != "fluid_blocks"} == {k: v for k, v in ours.items()
                                                                       if k != "fluid_blocks"}


def test_subcycled_scene_sets_the_standard_viscosity_alone_and_parses(tmp_path):
    ours = json.loads((ROOT / "scenes/bench/dambreak3d_r010.json").read_text())
    ours["effects"] = ["viscosity_standard", {"name": "viscosity_xsph", "coefficient": 0.1},
                       {"name": "viscosity_standard", "boundary_viscosity": 0.02}]
    s = bench_reference.subcycled(ours)
    assert s["effects"] == [{"name": "viscosity_standard", "subcycle": True},
                            {"name": "viscosity_xsph", "coefficient": 0.1},
                            {"name": "viscosity_standard", "boundary_viscosity": 0.02, "subcycle": True}]
    assert ours["effects"][0] == "viscosity_standard"  # the caller's scene is not modified
    # flowclip takes the changed scene (one standard viscosity: the shipped bench scene's).
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(bench_reference.subcycled(json.loads(
        (ROOT / "scenes/bench/dambreak3d_r010.json").read_text()))))
    out = subprocess.run([str(FLOWCLIP_BIN), "run", str(path), "--frames", "0", "--quiet"], capture_output=True,
                         text=True)
    assert out.returncode == 0, out.stdout + out.stderr


def test_reference_refuses_a_scene_of_another_solver():
    ours = json.loads((ROOT / "scenes/bench/dambreak2d_r010.json").read_text())
    ours["solver"] = {"method": "wcsph"}
    with pytest.raises(ValueError, match="wcsph"):
        bench_reference.reference_scene(ours, SHIPPED)


# Lines as SPlisHSPlasH 2.19 prints them at the end of a run (3D r = 0.0125).
OUTPUT = """Number of fluid particles: 59319
Average time: SimStep: 127.177 ms
---------------------------------------------------------------------------
Time sum: SimStep: 156300 ms
Time sum: pressureSolve: 38694.4 ms
Time sum: neighborhood_search: 79335.9 ms
---------------------------------------------------------------------------
Average number: Time step size: 0.00162537
Average number: DFSPH - iterations: 4.73881
Average number: DFSPH - iterationsV: 1.00325
---------------------------------------------------------------------------
Total number: Time step size: 1.99759
Total number: DFSPH - iterations: 5824
DRIVER {"steps": 1229, "particles": 59319, "peak_rss_mb": 97.4}
"""


def test_reference_figures_from_its_summary():
    r = bench_reference.parse_reference_output(OUTPUT)
    assert r["steps"] == 1229 and r["particles"] == 59319
    assert r["simulated_s"] == pytest.approx(1.99759)
    # SimStep's sum over steps × particles; not the neighbour search's line.
    assert r["us_per_particle_step"] == pytest.approx(156300e3 / (1229 * 59319))
    assert r["wall_s_per_simulated_s"] == pytest.approx(156.3 / 1.99759)
    assert r["density_iterations_per_step"] == pytest.approx(4.73881)
    assert r["divergence_iterations_per_step"] == pytest.approx(1.00325)
    assert r["peak_rss_mb"] == pytest.approx(97.4)


@pytest.mark.parametrize("drop", ["Time sum: SimStep", "DRIVER", "Total number: Time step size"])
def test_reference_output_missing_a_figure_is_an_error(drop):
    out = "\n".join(line for line in OUTPUT.splitlines() if not line.startswith(drop))
    with pytest.raises(RuntimeError):
        bench_reference.parse_reference_output(out)


def run_figures(us, wall, particles=5476, steps=1600):
    return {"particles": particles, "steps": steps, "simulated_s": 2.0, "us_per_particle_step": us,
            "wall_s_per_simulated_s": wall, "density_iterations_per_step": 3.5,
            "divergence_iterations_per_step": 1.0, "peak_rss_mb": 20.0}


def report_of(results, target_met):
    scenes = {name: {**runs, "ratios": bench_reference.ratios(runs)} for name, runs in results.items()}
    return {"benchmark": "reference", "date": "2026-01-01T00:00:00Z", "command": "tools/bench_reference.py --repeat 2",
            "machine": {"cpu": "Test CPU", "cores": 2, "loadavg_at_start": "0.1 0.1 0.1"}, "loadavg_at_end": "0.2 0.1 0.1",
            "settings": {"threads": 2, "seconds": 2.0, "repeat": 2, "reference": bench_reference.WHEEL,
                         "flowclip": "build/flowclip", "flowclip_version": "0.1.0"},
            "target": {"max_pct_of_reference": bench_reference.TARGET_PCT, "met": target_met},
            "scenes": scenes, "scenes_runs": results}


def test_report_divides_each_pair_and_writes_markdown_and_json(tmp_path):
    results = {"2d_r010": {"flowclip": [run_figures(0.30, 1.5), run_figures(0.40, 1.6)],
                           "splishsplash": [run_figures(1.00, 5.0, steps=1500), run_figures(1.00, 4.0, steps=1500)]}}
    q = bench_reference.ratios(results["2d_r010"])
    assert q["us_pct"] == pytest.approx([30.0, 40.0]) and q["wall_pct"] == pytest.approx([30.0, 40.0])
    bench_reference.write_report(tmp_path, report_of(results, True))
    md = (tmp_path / "reference.md").read_text()
    data = json.loads((tmp_path / "reference.json").read_text())
    assert data["machine"]["cpu"] == "Test CPU" and data["command"] in md and "Test CPU" in md
    assert "scenes_runs" not in data and data["scenes"]["2d_r010"]["ratios"] == q
    row = next(line for line in md.splitlines() if line.startswith("| 2d_r010 |"))
    # Medians with ranges, both figures divided pair by pair.
    assert "0.350 (0.300–0.400) vs 1.000" in row and "35.0 (30.0–40.0) %, 35.0 (30.0–40.0) %" in row
    assert "**met** (worst pair 40.0 %)" in md
    assert "moved onto SPlisHSPlasH's shipped one, particle on particle" in md
    assert not list(tmp_path.glob(".*.tmp")), "a temporary file was left"


def test_paper_size_target_reads_the_large_scenes_wall_time_alone(tmp_path):
    small = {"flowclip": [run_figures(0.3, 1.5)], "splishsplash": [run_figures(1.0, 2.0)]}  # 75 %, 5 476 particles
    big = {"flowclip": [run_figures(0.3, 3.2, particles=117_649), run_figures(0.3, 3.6, particles=117_649)],
           "splishsplash": [run_figures(1.0, 10.0, particles=117_649)] * 2}  # 32 % and 36 %
    scenes = {name: {**runs, "ratios": bench_reference.ratios(runs)} for name, runs in
              {"2d_r010": small, "3d_r010": big}.items()}
    t = bench_reference.large_target(scenes)
    assert t["scene"] == "3d_r010" and t["worst_pct"] == pytest.approx(36.0) and not t["met"]
    assert bench_reference.large_target({"2d_r010": scenes["2d_r010"]}) is None
    big_fast = {"flowclip": [run_figures(0.3, 2.5, particles=117_649)],
                "splishsplash": [run_figures(1.0, 10.0, particles=117_649)]}
    assert bench_reference.large_target({"3d_r010": {**big_fast, "ratios": bench_reference.ratios(big_fast)}})["met"]
    report = report_of({"2d_r010": small, "3d_r010": big}, False)
    report["target"]["large"] = t
    bench_reference.write_report(tmp_path, report)
    md = (tmp_path / "reference.md").read_text()
    assert "Target at 100,000 particles and more: at most 30 % of SPlisHSPlasH's wall time per simulated second: " \
           "**not met** (worst pair 36.0 %, 3d_r010)." in md
    assert json.loads((tmp_path / "reference.json").read_text())["target"]["large"]["worst_pct"] == pytest.approx(36.0)



def test_reference_mass_comes_from_the_driver_line():
    out = OUTPUT.replace('"peak_rss_mb": 97.4}', '"peak_rss_mb": 97.4, "mass": 0.008}')
    assert bench_reference.parse_reference_output(out)["mass"] == pytest.approx(0.008)
    assert bench_reference.parse_reference_output(OUTPUT)["mass"] is None


def test_an_audit_scene_exports_its_liquid_and_a_timed_one_does_not(tmp_path):
    (tmp_path / "Scenes").mkdir()
    (tmp_path / "Scenes" / "DamBreakModel.json").write_text(json.dumps(SHIPPED))
    timed, audited = tmp_path / "timed.json", tmp_path / "audited.json"
    bench_reference.write_reference_scene(str(tmp_path), "3d_r010", str(timed))
    bench_reference.write_reference_scene(str(tmp_path), "3d_r010", str(audited), export_fps=2.5)
    t = json.loads(timed.read_text())["Configuration"]
    a = json.loads(audited.read_text())["Configuration"]
    assert "enableVTKExport" not in t and "dataExportFPS" not in t
    assert a["enableVTKExport"] is True and a["dataExportFPS"] == 2.5
    assert {k: v for k, v in a.items() if k not in ("enableVTKExport", "dataExportFPS")} == t


def audit_summary(share, deviation, compression, p99, worst):
    return {"frames": [{}] * 5, "interior_share": share, "mean_deviation_pct": deviation,
            "mean_compression_pct": compression, "p99_compression_pct": p99, "max_mean_compression_pct": worst}


def test_report_shows_both_codes_density_measured_from_their_frames(tmp_path):
    results = {"3d_r010": {"flowclip": [run_figures(0.3, 1.5)], "splishsplash": [run_figures(1.0, 5.0)]}}
    report = report_of(results, True)
    report["density_audit"] = {"3d_r010": {"density_tolerance_pct": 0.05,
                                           "flowclip": audit_summary(0.78, -0.044, 0.046, 0.357, 0.051),
                                           "splishsplash": audit_summary(0.82, 0.068, 0.076, 0.313, 0.120)}}
    bench_reference.write_report(tmp_path, report)
    md = (tmp_path / "reference.md").read_text()
    assert "## The density each code holds, measured from its exported frames" in md
    row = [line for line in md.splitlines() if line.startswith("| 3d_r010 |")][-1]
    assert row == ("| 3d_r010 | 0.05 % | 5 / 5 | 0.78 / 0.82 | -0.044 % / 0.068 % | 0.046 % / 0.076 % "
                   "| 0.357 % / 0.313 % | 0.051 % / 0.120 % |")
    assert json.loads((tmp_path / "reference.json").read_text())["density_audit"]["3d_r010"]["flowclip"][
        "mean_compression_pct"] == pytest.approx(0.046)
