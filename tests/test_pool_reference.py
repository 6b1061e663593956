"""tools/pool_reference.py without SPlisHSPlasH itself: the two pools it
writes are the same pool with the same settings, the speeds it reports are
read from both codes' files, and the report says what it measured."""

from __future__ import annotations

import json
import pathlib
import sys

import h5py
import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
import density_audit  # noqa: E402  (tools/)
import pool_reference  # noqa: E402

# The shape of SPlisHSPlasH's shipped 2D dam break (its tank 4 m square on the floor y = 0).
SHIPPED = {
    "Configuration": {
        "particleRadius": 0.025, "sim2D": True, "pause": True, "gravitation": [0, -9.81, 0],
        "cflMethod": 1, "cflFactor": 1, "cflMaxTimeStepSize": 0.005, "boundaryHandlingMethod": 2,
        "DFSPH": {"minIterations": 2, "maxIterations": 100, "maxError": 0.1, "maxIterationsV": 100,
                  "maxErrorV": 0.1, "enableDivergenceSolver": True},
    },
    "Materials": [{"id": "Fluid", "density0": 1000, "viscosityMethod": 1, "vorticityMethod": 1,
                   "Standard viscosity": {"viscosity": 0.01}}],
    "RigidBodies": [{"geometryFile": "../models/UnitBox.obj", "translation": [0, 2.0, 0], "scale": [4, 4, 1],
                     "isWall": True}],
    "FluidBlocks": [{"start": [-2.0, 0.0, -1], "end": [-0.5, 1.5, 1], "translation": [0.025, 0.025, 0.0]}],
}


def ours():
    return json.loads((ROOT / pool_reference.SCENE).read_text())


def reference_particles(block, r):
    """SPlisHSPlasH's particle centres along each axis: start + 2r + 2r j, j < round((end - start) / 2r) - 1."""
    return [[block["start"][d] + 2 * r + 2 * r * j for j in range(round((block["end"][d] - block["start"][d]) / (2 * r)) - 1)]
            for d in range(2)]


@pytest.mark.parametrize("viscosity", [0.01, 0.0])
def test_both_pools_are_the_same_pool_with_the_same_settings(viscosity):
    mine, theirs = pool_reference.pool_scenes(ours(), SHIPPED, viscosity, "akinci2012", "akinci")
    r = mine["particle_radius"]
    (block,) = theirs["FluidBlocks"]
    assert block["start"][:2] == [-2.0, 0.0] and block["end"][:2] == [2.0, pool_reference.DEPTH]
    assert block["translation"] == [0, 0, 0]
    # Ours in a domain of the tank's size, particle on particle (our centres at min + r + 2r i, the tank's
    # lower corner our domain's).
    assert mine["domain"] == {"min": [0.0, 0.0], "max": [4, 4]}
    for d, centres in enumerate(reference_particles(block, r)):
        (b,) = mine["fluid_blocks"]
        first = b["min"][d] + r
        count = round((b["max"][d] - b["min"][d]) / (2 * r))
        assert first - 2.0 * (d == 0) == pytest.approx(centres[0])
        assert count == len(centres)
    assert mine["boundary"] == {"method": "akinci2012"}
    assert mine["phases"][0]["viscosity"] == viscosity
    effects = [e if isinstance(e, str) else e["name"] for e in mine.get("effects", [])]
    assert ("viscosity_standard" in effects) == (viscosity > 0)
    c = theirs["Configuration"]
    assert c["particleRadius"] == r and c["boundaryHandlingMethod"] == 0
    assert c["DFSPH"]["maxError"] == mine["solver"]["density_tolerance_pct"]
    assert c["DFSPH"]["maxErrorV"] == mine["solver"]["divergence_tolerance_pct"]
    assert c["DFSPH"]["maxIterations"] == mine["solver"]["max_iterations"]
    assert c["cflMaxTimeStepSize"] == mine["settings"]["dt_max"]
    assert theirs["Materials"][0]["Standard viscosity"] == {"viscosity": viscosity}
    assert c["enableVTKExport"] is True and c["particleAttributes"] == "velocity"
    assert c["dataExportFPS"] == pytest.approx(1 / pool_reference.SAMPLE)
    # The scene's own boundary where none is named.
    assert pool_reference.pool_scenes(ours(), SHIPPED, 0.01, None, "volume-maps")[0]["boundary"] == ours()["boundary"]


def test_speeds_are_the_rms_and_the_fastest_from_the_settled_time_on():
    times = [0.0, 0.5, 1.0, 1.5]
    v = [np.array([[3.0, 4.0], [0.0, 0.0]]),   # 5 m/s before 1 s: not counted
         np.array([[0.0, 2.0], [0.0, 0.0]]),
         np.array([[0.0, 0.03], [0.04, 0.0]]),
         np.array([[0.0, 0.01], [0.0, 0.01]])]
    s = pool_reference.speeds(times, v)
    assert s["max_after"] == pytest.approx(0.04)
    assert s["rms_at_end"] == pytest.approx(0.01)
    assert s["frames"][0] == {"time": 0.0, "rms": pytest.approx(np.sqrt(12.5)), "max": pytest.approx(5.0)}
    with pytest.raises(ValueError):
        pool_reference.speeds(times[:2], v[:2])


def test_velocities_are_read_from_both_codes_files(tmp_path):
    n = 3
    v = np.array([[1, 2, 0], [3, 4, 0], [5, 6, 0]], dtype=">f4")
    vtk = tmp_path / "ParticleData_Fluid_2.vtk"
    vtk.write_bytes(b"# vtk DataFile Version 4.1\nSPlisHSPlasH particle data\nBINARY\nDATASET UNSTRUCTURED_GRID\n"
                    + f"POINTS {n} float\n".encode() + np.zeros((n, 3), ">f4").tobytes()
                    + f"\nPOINT_DATA {n}\nFIELD FieldData 1\nvelocity 3 {n} float\n".encode() + v.tobytes())
    np.testing.assert_array_equal(density_audit.read_vtk_field(str(vtk), "velocity"), v.astype(float))
    # The file's time from its number, frame 1 at t = 0, as for the positions.
    ((t, read),) = density_audit.vtk_frames([str(vtk)], 10, 3,
                                            read=lambda f: density_audit.read_vtk_field(f, "velocity"))
    assert t == pytest.approx(0.1)
    np.testing.assert_array_equal(read, v.astype(float))
    bare = tmp_path / "bare.vtk"
    bare.write_bytes(f"POINTS {n} float\n".encode() + np.zeros((n, 3), ">f4").tobytes())
    with pytest.raises(ValueError, match="velocity"):
        density_audit.read_vtk_field(str(bare), "velocity")
    h5 = tmp_path / "ours.h5"
    with h5py.File(h5, "w") as f:
        f["frames/time"] = np.array([0.0, 0.5, 1.0, 1.5])
        f["frames/offset"] = np.array([0, 2, 4, 6], dtype=np.uint64)
        f["particles/velocity"] = np.arange(16, dtype=np.float32).reshape(8, 2)
    times, vels = pool_reference.our_frames(str(h5), 2)
    assert list(times) == [0.0, 1.0]
    np.testing.assert_array_equal(vels[1], [[8, 9], [10, 11]])


def test_report_writes_each_case_with_both_codes():
    frames = [{"time": 1.0, "rms": 0.02, "max": 0.07}, {"time": 1.1, "rms": 0.019, "max": 0.06}]
    case = {"viscosity": 0.01, "boundary": "adami2012", "reference_boundary": "volume-maps",
            "flowclip": {"frames": frames, "max_after": 0.07, "rms_at_end": 0.019, "particles": 9751},
            "splishsplash": {"frames": frames[:1], "max_after": 0.1, "rms_at_end": 0.012, "particles": 9751}}
    report = {"date": "2026-12-07T00:00:00Z", "command": "build/venv/bin/python tools/pool_reference.py",
              "machine": {"cpu": "cpu", "cores": 2, "loadavg_at_start": "1 1 1"}, "loadavg_at_end": "1 1 1",
              "settings": {"reference": "pysplishsplash==2.19.0", "flowclip_version": "0.1.0"}, "cases": [case]}
    md = pool_reference.markdown(report)
    assert "| 0.01 | `adami2012` | volume-maps | 9751 / 9751 | 70.0 | 19.0 | 100.0 | 12.0 |" in md
    assert "| 1.0 | 20.0 | 70.0 | 20.0 | 70.0 |" in md and "| 1.1 | 19.0 | 60.0 | - | - |" in md
