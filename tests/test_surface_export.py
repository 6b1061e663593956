"""Surfaces and the files DCCs import (docs/surfaces.md), read back by
readers that are not FlowClip's: OpenVDB's `vdb_print`, `plyfile`,
`usd-core` (pxr) and Blender (Debian's 3.4, and PyPI's bpy 4.2 for USD).

One run of the resting 3D column writes every format plus the HDF5
particle export; the tests compare what each reader sees with the
particles of the same frame.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest
from plyfile import PlyData
from pxr import Usd, UsdGeom

from repo_paths import FLOWCLIP_BIN, ROOT
from service_helpers import wait_until

SCENE = ROOT / "scenes" / "hydrostatic3d.json"
FRAMES = 30  # half a second: the column has settled into a resting pool
RADIUS = 0.01


def run(*args, check=True, timeout=600):
    proc = subprocess.run([str(FLOWCLIP_BIN), *map(str, args)], capture_output=True, text=True, timeout=timeout)
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    out = tmp_path_factory.mktemp("surface")
    run("run", SCENE, "--frames", FRAMES, "--threads", 2, "--quiet", "--export", out / "pool.h5",
        "--export-surface", out / "files", "--formats", "vdb,ply,points,obj,usd", "--format-setting", "usd.meshes=1")
    return out


def frame_rows(h5: Path, frame: int):
    with h5py.File(h5, "r") as f:
        i = int(np.nonzero(f["frames/index"][:] == frame)[0][0])
        a, b = f["frames/offset"][i], f["frames/offset"][i + 1]
        return {k: f[f"particles/{k}"][a:b] for k in ("position", "velocity", "id", "phase", "kind", "density")}


def read_mesh(path: Path):
    ply = PlyData.read(str(path))
    v = ply["vertex"]
    points = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64)
    faces = np.stack(ply["face"]["vertex_indices"]).astype(np.int64)
    return ply, points, faces


def enclosed_volume(points, faces):
    a, b, c = points[faces[:, 0]], points[faces[:, 1]], points[faces[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def edges_closed(faces):
    """Every directed edge appears once and its reverse once: closed and consistently oriented."""
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    keys = directed[:, 0] * (1 << 32) + directed[:, 1]
    reverse = directed[:, 1] * (1 << 32) + directed[:, 0]
    unique, counts = np.unique(keys, return_counts=True)
    return bool((counts == 1).all() and np.isin(reverse, unique).all())


def test_manifest_lists_every_frame_and_file(exported):
    files = exported / "files"
    manifest = json.loads((files / "hydrostatic3d.export.json").read_text())
    assert manifest["format"] == "flowclip-surface-export" and manifest["format_version"] == 1
    assert manifest["formats"] == ["vdb", "ply", "points", "obj", "usd"]
    assert [f["frame"] for f in manifest["frames"]] == list(range(FRAMES + 1))
    assert manifest["files"] == ["hydrostatic3d.usda"]
    for f in manifest["frames"]:
        n = f"{f['frame']:04d}"
        assert f["files"] == [f"hydrostatic3d.{n}.vdb", f"hydrostatic3d.{n}.ply", f"hydrostatic3d_points.{n}.ply",
                              f"hydrostatic3d.{n}.obj"]
        for name in f["files"]:
            assert (files / name).stat().st_size > 0
    # Nothing left under a temporary name.
    assert not [p.name for p in files.iterdir() if p.name.startswith(".")]


def test_vdb_print_reads_a_level_set_and_a_velocity_grid(exported):
    out = subprocess.run(["vdb_print", "-l", "-m", str(exported / "files" / "hydrostatic3d.0010.vdb")],
                         capture_output=True, text=True, check=True, timeout=120).stdout
    grids = dict(re.findall(r"Name: (\w+)\nInformation about Tree:\n  Type: (\w+)", out))
    assert grids == {"surface": "Tree_float_5_4_3", "v": "Tree_vec3s_5_4_3"}, out
    assert "class: level set" in out
    assert re.search(r"^  frame: 10$", out, re.M)
    voxel = float(re.search(r"voxel size: ([0-9.eE+-]+)", out).group(1))
    assert voxel == pytest.approx(0.5 * RADIUS)


def test_resting_pool_mesh_is_closed_and_holds_the_liquid_volume(exported):
    rows = frame_rows(exported / "pool.h5", FRAMES)
    liquid = rows["position"][rows["kind"] <= 1].astype(np.float64)
    _, points, faces = read_mesh(exported / "files" / f"hydrostatic3d.{FRAMES:04d}.ply")
    assert edges_closed(faces)
    volume = enclosed_volume(points, faces)
    particles = len(liquid) * (2 * RADIUS) ** 3
    assert volume == pytest.approx(particles, rel=0.02), (volume, particles)
    # No vertex is farther than one radius from some particle's sphere.
    nearest = np.full(len(points), np.inf)
    for chunk in np.array_split(np.arange(len(points)), max(1, len(points) // 2000)):
        d = np.linalg.norm(points[chunk, None, :] - liquid[None, :, :], axis=2)
        nearest[chunk] = d.min(axis=1)
    assert nearest.max() <= 2 * RADIUS, nearest.max() / RADIUS


def test_mesh_vertices_move_with_the_liquid(exported):
    """Per-vertex velocity is a weighted mean of the nearby particles': within their range, not zero."""
    ply, points, _ = read_mesh(exported / "files" / "hydrostatic3d.0002.ply")
    assert [p.name for p in ply["vertex"].properties] == ["x", "y", "z", "vx", "vy", "vz"]
    rows = frame_rows(exported / "pool.h5", 2)
    v = np.stack([ply["vertex"]["vx"], ply["vertex"]["vy"], ply["vertex"]["vz"]], axis=1)
    lo, hi = rows["velocity"].min(axis=0), rows["velocity"].max(axis=0)
    assert (v >= lo - 1e-6).all() and (v <= hi + 1e-6).all()
    assert np.abs(v).max() > 0.1 * np.abs(rows["velocity"]).max() > 0


def test_point_cache_holds_the_particles_of_the_frame(exported):
    frame = 12
    rows = frame_rows(exported / "pool.h5", frame)
    ply = PlyData.read(str(exported / "files" / f"hydrostatic3d_points.{frame:04d}.ply"))
    v = ply["vertex"]
    assert [p.name for p in v.properties] == ["x", "y", "z", "vx", "vy", "vz", "id", "phase", "kind", "density"]
    keep = rows["kind"] <= 1
    np.testing.assert_array_equal(v["id"], rows["id"][keep])
    np.testing.assert_array_equal(np.stack([v["x"], v["y"], v["z"]], 1), rows["position"][keep])
    np.testing.assert_array_equal(np.stack([v["vx"], v["vy"], v["vz"]], 1), rows["velocity"][keep])
    np.testing.assert_array_equal(v["density"], rows["density"][keep])
    np.testing.assert_array_equal(v["phase"], rows["phase"][keep])


def test_obj_holds_the_same_mesh(exported):
    frame = 5
    _, points, faces = read_mesh(exported / "files" / f"hydrostatic3d.{frame:04d}.ply")
    text = (exported / "files" / f"hydrostatic3d.{frame:04d}.obj").read_text().splitlines()
    v = np.array([[float(x) for x in line.split()[1:]] for line in text if line.startswith("v ")])
    f = np.array([[int(x) for x in line.split()[1:]] for line in text if line.startswith("f ")]) - 1
    np.testing.assert_allclose(v, points, rtol=0, atol=1e-7)
    np.testing.assert_array_equal(f, faces)


def test_usd_stage_is_time_sampled(exported):
    stage = Usd.Stage.Open(str(exported / "files" / "hydrostatic3d.usda"))
    assert stage.GetTimeCodesPerSecond() == 60
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, FRAMES)
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    points = UsdGeom.Points(stage.GetPrimAtPath("/flowclip/particles"))
    assert points.GetPointsAttr().GetTimeSamples() == list(range(FRAMES + 1))
    assert list(points.GetWidthsAttr().Get()) == pytest.approx([2 * RADIUS])
    for frame in (0, 7, FRAMES):
        rows = frame_rows(exported / "pool.h5", frame)
        keep = rows["kind"] <= 1
        np.testing.assert_array_equal(np.array(points.GetIdsAttr().Get(frame)), rows["id"][keep])
        np.testing.assert_allclose(np.array(points.GetPointsAttr().Get(frame)), rows["position"][keep], rtol=1e-6)
        np.testing.assert_allclose(np.array(points.GetVelocitiesAttr().Get(frame)), rows["velocity"][keep], rtol=1e-6,
                                   atol=1e-9)
    assert UsdGeom.PrimvarsAPI(points).GetPrimvar("phase").GetInterpolation() == UsdGeom.Tokens.vertex
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/flowclip/surface"))
    _, ply_points, ply_faces = read_mesh(exported / "files" / "hydrostatic3d.0009.ply")
    assert len(mesh.GetPointsAttr().Get(9)) == len(ply_points)
    np.testing.assert_array_equal(np.array(mesh.GetFaceVertexIndicesAttr().Get(9)).reshape(-1, 3), ply_faces)
    assert set(mesh.GetFaceVertexCountsAttr().Get(9)) == {3}


def test_export_command_rebuilds_the_same_files_from_the_particle_export(exported, tmp_path):
    proc = run("export", exported / "pool.h5", "--out", tmp_path, "--name", "hydrostatic3d", "--formats", "ply,points",
               "--first", 3, "--last", 5, "--threads", 2)
    assert re.search(r"3/3 frames", proc.stderr), proc.stderr
    manifest = json.loads((tmp_path / "hydrostatic3d.export.json").read_text())
    assert [f["frame"] for f in manifest["frames"]] == [3, 4, 5]
    for frame in (3, 4, 5):
        for name in (f"hydrostatic3d.{frame:04d}.ply", f"hydrostatic3d_points.{frame:04d}.ply"):
            assert (tmp_path / name).read_bytes() == (exported / "files" / name).read_bytes(), name


def test_blender_imports_the_mesh_and_the_volume(exported, tmp_path):
    blender = shutil.which("blender")
    assert blender, "blender is installed by make setup (tools/setup.sh)"
    script = tmp_path / "import.py"
    script.write_text(
        "import bpy, json, sys\n"
        "d = sys.argv[sys.argv.index('--') + 1]\n"
        "bpy.ops.wm.read_factory_settings(use_empty=True)\n"
        "out = {}\n"
        "bpy.ops.import_mesh.ply(filepath=d + '/hydrostatic3d.0004.ply')\n"
        "o = bpy.context.selected_objects[0]; out['ply'] = [len(o.data.vertices), len(o.data.polygons)]\n"
        "bpy.ops.import_scene.obj(filepath=d + '/hydrostatic3d.0004.obj')\n"
        "o = bpy.context.selected_objects[0]; out['obj'] = [len(o.data.vertices), len(o.data.polygons)]\n"
        "bpy.ops.object.volume_import(filepath=d + '/hydrostatic3d.0004.vdb')\n"
        "o = bpy.context.selected_objects[0]; o.data.grids.load()\n"
        "out['vdb'] = sorted(g.name for g in o.data.grids)\n"
        "print('IMPORTED ' + json.dumps(out))\n")
    proc = subprocess.run([blender, "-b", "--factory-startup", "--python", str(script), "--", str(exported / "files")],
                          capture_output=True, text=True, timeout=600)
    found = re.search(r"^IMPORTED (.*)$", proc.stdout, re.M)
    assert found, proc.stdout[-2000:] + proc.stderr[-2000:]
    got = json.loads(found.group(1))
    _, points, faces = read_mesh(exported / "files" / "hydrostatic3d.0004.ply")
    assert got["ply"] == [len(points), len(faces)]
    assert got["obj"] == [len(points), len(faces)]
    assert got["vdb"] == ["surface", "v"]


BLENDER_PYTHON = ROOT / "build" / "venv-blender" / "bin" / "python"


def test_blender_imports_the_usd_stage_with_its_time_samples(exported, tmp_path):
    """PyPI's bpy (Debian's blender lacks USD): points and surface play frame by frame, upright."""
    assert BLENDER_PYTHON.exists(), "the bpy venv is made by make setup (tools/setup.sh, requirements-blender.txt)"
    script = tmp_path / "import_usd.py"
    script.write_text(
        "import bpy, json, sys\n"
        "bpy.ops.wm.read_factory_settings(use_empty=True)\n"
        "bpy.ops.wm.usd_import(filepath=sys.argv[1], set_frame_range=True)\n"
        "s = bpy.context.scene\n"
        "out = {'range': [s.frame_start, s.frame_end], 'types': {o.name: o.type for o in bpy.data.objects}}\n"
        "for frame in (4, 9):\n"
        "    s.frame_set(frame)\n"
        "    dg = bpy.context.evaluated_depsgraph_get()\n"
        "    p = bpy.data.objects['particles'].evaluated_get(dg).data.points\n"
        "    m = bpy.data.objects['surface'].evaluated_get(dg).data\n"
        "    out[frame] = {'points': [list(q.co) for q in p], 'vertices': [list(v.co) for v in m.vertices],\n"
        "                  'polygons': len(m.polygons)}\n"
        "w = bpy.data.objects['surface'].matrix_world\n"
        "out['up'] = list(w.to_3x3() @ __import__('mathutils').Vector((0, 1, 0)))\n"
        "print('IMPORTED ' + json.dumps(out))\n")
    proc = subprocess.run([str(BLENDER_PYTHON), str(script), str(exported / "files" / "hydrostatic3d.usda")],
                          capture_output=True, text=True, timeout=600)
    found = re.search(r"^IMPORTED (.*)$", proc.stdout, re.M)
    assert found, proc.stdout[-2000:] + proc.stderr[-2000:]
    got = json.loads(found.group(1))
    assert got["range"] == [0, FRAMES]
    assert got["types"]["particles"] == "POINTCLOUD" and got["types"]["surface"] == "MESH"
    for frame in (4, 9):
        rows = frame_rows(exported / "pool.h5", frame)
        keep = rows["kind"] <= 1
        np.testing.assert_allclose(np.array(got[str(frame)]["points"]), rows["position"][keep], atol=1e-6)
        _, points, faces = read_mesh(exported / "files" / f"hydrostatic3d.{frame:04d}.ply")
        np.testing.assert_allclose(np.array(got[str(frame)]["vertices"]), points, atol=1e-6)
        assert got[str(frame)]["polygons"] == len(faces)
    # Our Y-up stage stands upright in Blender's Z-up world.
    np.testing.assert_allclose(got["up"], [0, 0, 1], atol=1e-6)


# Bad input: a clear error, exit status 2, and nothing under a final name.

def test_unknown_format_is_refused_naming_the_known_ones(tmp_path):
    proc = run("run", SCENE, "--frames", 1, "--export-surface", tmp_path / "out", "--formats", "vdb,stl", check=False)
    assert proc.returncode == 2
    assert "unknown export format 'stl' (known: obj, ply, points, svg, usd, vdb)" in proc.stderr
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())


def test_unwritable_directory_is_refused_before_simulating(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("a file where a directory should be")
    proc = run("run", SCENE, "--frames", 1, "--export-surface", blocker / "out", "--formats", "ply", check=False)
    assert proc.returncode == 2
    assert f"export directory '{blocker / 'out'}' cannot be created" in proc.stderr
    assert "frame 1/1" not in proc.stderr


def test_bad_surface_and_format_settings_name_their_key(tmp_path):
    proc = run("run", SCENE, "--frames", 1, "--export-surface", tmp_path, "--formats", "ply",
               "--surface", "voxel_size=0", check=False)
    assert proc.returncode == 2 and "surface.voxel_size: '0' given by --surface: must be in [0.1, 2]" in proc.stderr
    proc = run("run", SCENE, "--frames", 1, "--export-surface", tmp_path, "--formats", "ply",
               "--surface", "surface_radius=3", "--surface", "kernel_radius=2", check=False)
    assert proc.returncode == 2 and "surface_radius must be less than surface.kernel_radius" in proc.stderr
    proc = run("run", SCENE, "--frames", 1, "--export-surface", tmp_path, "--formats", "ply",
               "--format-setting", "usd.meshes=1", check=False)
    assert proc.returncode == 2 and "format 'usd' is not exported" in proc.stderr
    assert not list(tmp_path.iterdir())


def test_particle_export_of_another_version_is_refused(exported, tmp_path):
    other = tmp_path / "v2.h5"
    shutil.copy(exported / "pool.h5", other)
    with h5py.File(other, "r+") as f:
        f.attrs["format_version"] = np.int32(2)
    proc = run("export", other, "--out", tmp_path / "out", "--formats", "ply", check=False)
    assert proc.returncode == 2
    assert "has format_version 2; this flowclip reads version 1" in proc.stderr
    assert not (tmp_path / "out").exists()
    (tmp_path / "junk.h5").write_text("not HDF5")
    proc = run("export", tmp_path / "junk.h5", "--out", tmp_path / "out", "--formats", "ply", check=False)
    assert proc.returncode == 2 and "cannot be opened as HDF5" in proc.stderr


def test_a_killed_export_leaves_complete_frames_and_no_manifest(exported, tmp_path):
    out = tmp_path / "out"
    proc = subprocess.Popen([str(FLOWCLIP_BIN), "export", str(exported / "pool.h5"), "--out", str(out), "--formats",
                             "vdb,ply,usd", "--threads", "1", "--quiet"])
    wait_until(lambda: (out / "pool.0002.ply").exists(), timeout=300, what="frame 2 published")
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=60)
    assert (out / "pool.0002.ply").exists()
    assert not (out / "pool.export.json").exists()
    assert not (out / "pool.usda").exists()
    for ply in out.glob("pool.*.ply"):  # every published frame reads whole
        PlyData.read(str(ply))
    # The next export into the directory cleans up and completes.
    run("export", exported / "pool.h5", "--out", out, "--formats", "ply", "--last", 3, "--quiet")
    assert (out / "pool.export.json").exists()
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]


def test_a_2d_liquid_outline_in_svg_and_its_slab_and_area_in_ply(tmp_path):
    """The svg format, read with Python's own XML parser: closed loops around the resting 2D column
    whose area is its particles' (N (2r)²) within a few percent; the PLY mesh, read with plyfile, is a
    closed slab thickness_2d thick enclosing that area times the thickness, and at thickness_2d 0 the
    flat area itself, facing +z; a 3D scene's svg is refused."""
    import xml.etree.ElementTree as ET

    scene = ROOT / "scenes" / "hydrostatic2d.json"
    run("run", scene, "--frames", 2, "--quiet", "--export", tmp_path / "column.h5")
    run("export", tmp_path / "column.h5", "--out", tmp_path / "svg", "--formats", "svg,ply", "--quiet")
    run("export", tmp_path / "column.h5", "--out", tmp_path / "flat", "--formats", "ply", "--surface",
        "thickness_2d=0", "--quiet")
    radius = json.loads(scene.read_text())["particle_radius"]
    root = ET.parse(tmp_path / "svg" / "column.0002.svg").getroot()
    assert root.tag == "{http://www.w3.org/2000/svg}svg"
    d = root.find("{http://www.w3.org/2000/svg}path").get("d")
    loops = [np.array([[float(t[1:] if t[0] in "ML" else t) for t in pair] for pair in
                       re.findall(r"[ML](\S+) (\S+)", loop)]) for loop in d.split("Z") if loop.strip()]
    assert len(loops) == 1 and len(loops[0]) > 20
    x, y = loops[0][:, 0], -loops[0][:, 1]  # SVG's y points down
    area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    liquid = int(np.sum(frame_rows(tmp_path / "column.h5", 2)["kind"] == 0))
    assert abs(area / (liquid * 4 * radius**2) - 1) < 0.05
    _, points, faces = read_mesh(tmp_path / "svg" / "column.0002.ply")
    assert edges_closed(faces)
    thickness = 2.3 * radius
    assert np.allclose(np.abs(points[:, 2]), thickness / 2, atol=1e-7)
    assert abs(enclosed_volume(points, faces) / (area * thickness) - 1) < 1e-4
    _, points, faces = read_mesh(tmp_path / "flat" / "column.0002.ply")
    assert np.all(points[:, 2] == 0)
    a, b, c = points[faces[:, 0]], points[faces[:, 1]], points[faces[:, 2]]
    facing = 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1]))
    assert np.all(facing >= -1e-12) and abs(facing.sum() / area - 1) < 1e-4
    proc = run("run", SCENE, "--frames", 1, "--export-surface", tmp_path / "3d", "--formats", "svg", check=False)
    assert proc.returncode == 2 and "svg export: the outline of a 2D liquid" in proc.stderr
