"""`flowclip bench solver | scenes | service` at their smallest settings: each writes its
report (NAME.md + NAME.json, docs/benchmarks/) into --out, with the machine, date and
command, figures that fit the scene, and the same figures in the markdown as in the JSON.
`bench control`'s report: tests/test_bench_control.py."""
from __future__ import annotations

import json
import subprocess

import pytest

from bench_report_check import block_particles, lattice_particles, md_row, read_report, run_bench
from repo_paths import FLOWCLIP_BIN, ROOT

DAM = ROOT / "scenes" / "bench" / "dambreak2d_r010.json"
DROP = ROOT / "scenes" / "drop2d.json"
FRAME_RATE = 60


def test_solver_report(tmp_path):
    out = tmp_path / "solver"
    seconds = 0.05
    run_bench(["solver", "--scenes", str(DAM), "--seconds", str(seconds), "--threads", "1"], out)
    report, md = read_report(out, "solver")
    assert report["settings"]["seconds"] == seconds and report["machine"]["threads"] == 1
    assert report["failures"] == []
    runs = report["runs"]
    assert [r["solver"] for r in runs] == ["dfsph", "wcsph"]
    for r in runs:
        assert r["bench_scene"] == "dambreak2d_r010" and r["threads"] == 1
        assert r["liquid_particles"] == block_particles(DAM) == 74 * 74
        assert r["frames"] == round(seconds * FRAME_RATE)
        assert r["substeps"] >= r["frames"]
        assert r["us_per_particle_step"] > 0 and r["wall_s_per_simulated_s"] > 0 and r["ms_per_frame"] > 0
        assert r["peak_rss_mb"] > 0
        assert 0 <= r["mean_avg_density_error_pct"] <= r["max_density_error_pct"]
        stages = r["stage_ms_per_substep"]
        parts = [stages[k] for k in ("neighbor_ms", "density_ms", "divergence_ms", "non_pressure_ms", "pressure_ms")]
        assert all(p >= 0 for p in parts) and stages["total_ms"] == pytest.approx(sum(parts))
        # The stages are part of the step: together no longer than the run's wall time per substep.
        assert stages["total_ms"] <= 1000 * r["wall_s"] / r["substeps"]
        assert r["boundary"] == "akinci2012" and r["boundary_setup_ms"] >= 0 and r["boundary_model_bytes"] == 0
        row = md_row(r["bench_scene"], r["solver"], r["boundary"], r["liquid_particles"], r["substeps"],
                     f"{r['us_per_particle_step']:.3f}", f"{r['substeps_per_frame']:.1f}", f"{r['ms_per_frame']:.1f}",
                     f"{r['wall_s_per_simulated_s']:.2f}", f"{r['mean_avg_density_error_pct']:.4f}",
                     f"{r['max_density_error_pct']:.3f}",
                     "-" if r["density_tolerance_pct"] is None else f"{r['density_tolerance_pct']:g}",
                     f"{r['late_kinetic_energy']:.3g}", f"{r['final_max_speed']:.3f}",
                     f"{r['peak_rss_mb']:.0f}", f"{r['boundary_setup_ms']:.1f}", "0.00")
        assert row in md, row
        # A dam break in its first frames: everything is falling, the fastest faster than free fall's mean.
        assert r["late_kinetic_energy"] > 0 and r["final_max_speed"] > 9.81 * seconds / 2
        assert md_row(r["bench_scene"], r["solver"], r["boundary"], *(f"{p:.2f}" for p in parts),
                      f"{stages['total_ms']:.2f}",
                      f"{r['divergence_iterations_per_substep']:.2f}",
                      f"{r['density_iterations_per_substep']:.2f}") in md
    dfsph, wcsph = runs
    # The scene's own tolerance is held; WCSPH has none. DFSPH's density solve iterates at least once a substep.
    assert dfsph["density_tolerance_pct"] == 0.1 and wcsph["density_tolerance_pct"] is None
    assert dfsph["density_iterations_per_substep"] >= 1
    ref = dfsph["splishsplash_fixed"]
    assert ref["threads"] == 2
    assert ref["ours_us_pct"] == pytest.approx(100 * dfsph["us_per_particle_step"] / ref["us_per_particle_step"])
    assert "splishsplash_fixed" not in wcsph


def test_solver_report_runs_a_solver_with_its_parameters_set(tmp_path):
    out = tmp_path / "solver"
    run_bench(["solver", "--scenes", str(DAM), "--seconds", "0.05", "--threads", "1", "--solvers",
               "dfsph,dfsph:density_tolerance_pct=0.02:warm_start=0"], out)
    report, md = read_report(out, "solver")
    assert report["failures"] == []
    default, tight = report["runs"]
    assert (default["solver"], tight["solver"]) == ("dfsph", "dfsph:density_tolerance_pct=0.02:warm_start=0")
    # What the run held, read back from the child's own summary.
    assert default["density_tolerance_pct"] == 0.1 and tight["density_tolerance_pct"] == 0.02
    assert tight["solver_parameters"]["warm_start"] == 0 and default["solver_parameters"]["warm_start"] == 1
    assert tight["density_iterations_per_substep"] > default["density_iterations_per_substep"]
    assert "| dambreak2d_r010 | dfsph:density_tolerance_pct=0.02:warm_start=0 | akinci2012 |" in md


def test_solver_report_takes_the_fastest_of_rounds_that_take_turns(tmp_path):
    out = tmp_path / "solver"
    done = run_bench(["solver", "--scenes", str(DAM), "--seconds", "0.02", "--threads", "1", "--solvers",
                      "dfsph,wcsph", "--rounds", "2"], out)
    report, md = read_report(out, "solver")
    assert report["settings"]["rounds"] == 2 and report["failures"] == []
    # The cases take turns: every case once per round, round after round.
    started = [line.split("bench: ")[1] for line in done.stderr.splitlines() if line.startswith("bench: ")]
    assert started == [f"dambreak2d_r010 with {s} [round {k}/2] ..." for k in (1, 2) for s in ("dfsph", "wcsph")]
    assert [r["solver"] for r in report["runs"]] == ["dfsph", "wcsph"]
    for r in report["runs"]:
        assert r["rounds"] == 2
        assert len(r["wall_s_per_simulated_s_all"]) == 2 and len(r["us_per_particle_step_all"]) == 2
        assert r["wall_s_per_simulated_s"] == min(r["wall_s_per_simulated_s_all"])
        assert r["us_per_particle_step"] in r["us_per_particle_step_all"]
    assert "the fastest (wall s per simulated s) of 2 rounds" in md


def test_solver_report_compares_boundary_models(tmp_path):
    out = tmp_path / "solver"
    run_bench(["solver", "--scenes", str(DAM), "--seconds", "0.05", "--threads", "1", "--solvers", "dfsph",
               "--boundaries", "akinci2012,bender2019"], out)
    report, md = read_report(out, "solver")
    assert report["settings"]["boundaries"] == ["akinci2012", "bender2019"] and report["failures"] == []
    akinci, bender = report["runs"]
    assert (akinci["boundary"], bender["boundary"]) == ("akinci2012", "bender2019")
    # The volume map is built once and held: it takes set-up time and memory the samples alone do not.
    assert akinci["boundary_model_bytes"] == 0 and bender["boundary_model_bytes"] > 0
    assert bender["boundary_setup_ms"] > 0
    assert bender["liquid_particles"] == akinci["liquid_particles"]
    assert f"| {bender['bench_scene']} | dfsph | bender2019 |" in md


@pytest.mark.heavy
def test_scenes_report(template_dir, tmp_path):
    out = tmp_path / "scenes"
    frames = 14  # two frames past the drop's instance start (t = 0.2 s)
    run_bench(["scenes", str(DROP), str(DAM), "--frames", str(frames), "--threads", "1",
               "--templates", str(template_dir)], out)
    report, md = read_report(out, "scenes")
    assert report["failures"] == []
    drop, dam = report["scenes"]
    assert (drop["scene"], dam["scene"]) == ("drop2d", "dambreak2d_r010")
    for r in (drop, dam):
        assert r["frames"] == frames and 1 <= r["active_frames"] <= frames
        assert r["simulation_ms_per_frame"] > 0 and r["peak_rss_mb"] > 0
        assert r["control_pct"] == pytest.approx(100 * r["control_ms_per_frame"] / r["simulation_ms_per_frame"])
        assert md_row(r["scene"], f"{r['active_frames']} / {r['frames']}", *(f"{r[k]:.0f}" for k in (
            "liquid", "control", "repulsion", "temporary")), f"{r['simulation_ms_per_frame']:.1f}",
            f"{r['control_ms_per_frame']:.1f}", f"{r['control_pct']:.1f}", f"{r['peak_rss_mb']:.0f}",
            f"{r['template_storage_mb']:.2f}") in md
    # Without instances every frame counts, and nothing is controlled.
    assert dam["active_frames"] == frames and dam["liquid"] == block_particles(DAM)
    assert dam["control"] == dam["control_ms_per_frame"] == dam["template_storage_mb"] == 0
    # The drop's liquid is its block's (temporary particles counted apart), its template on disk.
    assert drop["liquid"] == pytest.approx(block_particles(DROP), rel=0.01)
    assert drop["active_frames"] < frames and drop["control"] > 0
    assert drop["template_storage_mb"] == pytest.approx((template_dir / "drop2d.h5").stat().st_size / 1e6)
    assert drop["paper"]["name"] == "2D Rectangular drop" and "paper" not in dam
    assert "| drop2d | 2D Rectangular drop | 6700 | 1300 | 88 | 36 | 190.2 | 5.6 | 2.9 | 0.33 | 3.87 |" in md


def test_scenes_report_counts_every_frame_where_no_instance_plays_yet(template_dir, tmp_path):
    out = tmp_path / "scenes"
    frames = 2  # the drop's instance starts at t = 0.2 s, frame 12
    run_bench(["scenes", str(DROP), "--frames", str(frames), "--threads", "1", "--templates", str(template_dir)], out)
    report, md = read_report(out, "scenes")
    [drop] = report["scenes"]
    assert drop["frames"] == frames and drop["active_frames"] == 0
    # The liquid is still the block's, not zero; nothing is controlled yet.
    assert drop["liquid"] == pytest.approx(block_particles(DROP), rel=0.01)
    assert drop["control"] == drop["repulsion"] == drop["temporary"] == 0
    assert f"| drop2d | 0 / {frames} | {drop['liquid']:.0f} | 0 | 0 | 0 |" in md


@pytest.mark.heavy
def test_scenes_report_at_the_papers_scale(tmp_path):
    # The drop's template at its paper scale, where `--scale paper` looks for it.
    templates = tmp_path / "templates"
    rec = subprocess.run([str(FLOWCLIP_BIN), "record", str(ROOT / "templates" / "recipes" / "drop2d.json"),
                          "--scale", "paper", "--templates", str(templates / "paper"), "--quiet"],
                         capture_output=True, text=True, timeout=600)
    assert rec.returncode == 0, rec.stderr
    out = tmp_path / "scenes"
    frames = 14  # SCENE:FRAMES wins over --frames
    done = subprocess.run([str(FLOWCLIP_BIN), "bench", "scenes", f"{DROP}:{frames}", str(DAM), "--frames", "2",
                           "--scale", "paper", "--threads", "1", "--templates", str(templates / "paper"),
                           "--out", str(out)], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert done.returncode != 0, "a scene without the scale is a failed run"
    report, md = read_report(out, "scenes")
    assert report["settings"]["scale"] == "paper"
    [drop] = report["scenes"]
    assert [f["scene"] for f in report["failures"]] == ["dambreak2d_r010"]
    assert report["failures"][0]["error"].startswith("exit 2")  # refused as bad input: it has no such scale
    assert drop["frames"] == frames
    scene = json.loads(DROP.read_text())
    radius = scene["scales"]["paper"]["particle_radius"]
    seeded = sum(lattice_particles(b["min"], b["max"], radius) for b in scene["fluid_blocks"])
    assert drop["liquid"] == pytest.approx(seeded, rel=0.01)
    assert drop["template_storage_mb"] == pytest.approx((templates / "paper" / "drop2d.h5").stat().st_size / 1e6)
    # The stages are parts of the frame's time.
    stages = drop["stages_ms_per_frame"]
    assert set(stages) == {"neighbor_ms", "density_ms", "divergence_ms", "non_pressure_ms", "pressure_ms"}
    assert all(v > 0 for v in stages.values())
    assert sum(stages.values()) <= drop["simulation_ms_per_frame"]
    assert md_row("drop2d", *(f"{stages[k]:.1f}" for k in ("neighbor_ms", "density_ms", "divergence_ms",
                                                            "non_pressure_ms", "pressure_ms")),
                  f"{drop['control_ms_per_frame']:.1f}", f"{drop['simulation_ms_per_frame']:.1f}") in md
    # Each figure over the paper's.
    ratio = md_row("drop2d", f"{drop['liquid'] / 6700:.2f}", f"{drop['control'] / 1300:.2f}",
                   f"{drop['simulation_ms_per_frame'] / 190.2:.2f}",
                   f"{drop['control_pct']:.1f} / {100 * 5.6 / 190.2:.1f}",
                   f"{drop['peak_rss_mb'] / 1024 / 0.33:.2f}", f"{drop['template_storage_mb'] / 3.87:.2f}")
    assert ratio in md, md


def test_service_report(template_dir, tmp_path):
    out = tmp_path / "service"
    particles, frames, clients = 2000, 5, [1, 2]
    run_bench(["service", "--particles", str(particles), "--seconds", "0.3", "--clients", ",".join(map(str, clients)),
               "--scene", str(DROP), "--frames", str(frames), "--templates", str(template_dir), "--threads", "1"], out)
    report, md = read_report(out, "service")
    assert report["settings"]["threads"] == report["machine"]["threads"] == 1
    idle = report["idle_server"]
    assert idle["rss_mb"] > 0
    assert md_row("RSS of `flowclip serve` without a session, MB", f"{idle['rss_mb']:.1f}") in md

    enc = report["encoding"]
    assert enc["particles"] == particles
    rec = enc["recorded"]
    assert rec["ms_per_frame"] > 0 and rec["repetitions"] >= 5
    assert rec["ns_per_particle"] == pytest.approx(rec["ms_per_frame"] * 1e6 / particles)
    # 3D: 6 bytes of position, 1 of kind, 1 of phase per particle, plus the message's header and instances.
    assert 8 <= enc["message"]["bytes_per_particle"] < 9
    assert enc["message"]["mb_per_frame"] == pytest.approx(enc["message"]["bytes_per_particle"] * particles / 1e6)
    assert enc["history_bytes_per_particle_frame"] >= 14
    assert md_row("recorded frame", particles, f"{rec['ms_per_frame']:.3f}", f"{rec['ns_per_particle']:.2f}",
                  f"{enc['message']['bytes_per_particle']:.2f}", rec["repetitions"]) in md
    # The live path's tank: a block of 0.93 × 0.93 × 0.46 m sampled for about `particles`.
    liquid, boundary = enc["live"]
    radius = 0.5 * (0.93 * 0.93 * 0.46 / particles) ** (1 / 3)
    assert liquid["particles"] == lattice_particles([0, 0, 0], [0.93, 0.93, 0.46], radius)
    assert boundary["particles"] > liquid["particles"]
    for live in (liquid, boundary):
        assert live["ms_per_frame"] > 0 and live["bytes_per_particle"] >= 8
        assert md_row(f"live, {live['layers']}", live["particles"], f"{live['ms_per_frame']:.3f}",
                      f"{live['ns_per_particle']:.2f}", f"{live['bytes_per_particle']:.2f}",
                      live["repetitions"]) in md

    stream = report["streaming"]
    assert stream["particles"] == particles and [r["clients"] for r in stream["runs"]] == clients
    for r in stream["runs"]:
        assert 0 < r["min_frames_per_s"] <= r["frames_per_s_each"] and r["mb_per_s_total"] > 0
        assert r["published_per_s"] > 0
        assert md_row(r["clients"], *(f"{r[k]:.1f}" for k in ("frames_per_s_each", "min_frames_per_s",
                                                                "mb_per_s_total", "published_per_s"))) in md

    mem = report["session_memory"]
    assert mem["liquid_particles"] == block_particles(DROP) and mem["frames"] == frames
    assert mem["simulation_state_mb"] > 0 and mem["history_mb_per_1000_frames"] > 0 and mem["checkpoints_mb"] >= 0
    assert md_row("history per 1000 frames, counted by the session", f"{mem['history_mb_per_1000_frames']:.2f}") in md
    assert md_row("checkpoints after the last frame, counted by the session", f"{mem['checkpoints_mb']:.2f}") in md
