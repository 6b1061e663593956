"""tools/density_audit.py: the density measured from exported positions alone.
Its sums against a brute-force sum, a resting and a compressed lattice, the
interior it keeps, SPlisHSPlasH's VTK layout, and FlowClip's own export of a
resting column measured against the column's tolerance."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from repo_paths import FLOWCLIP_BIN, ROOT  # tests/, beside this file

sys.path.insert(0, str(ROOT / "tools"))
import density_audit  # noqa: E402

R = 0.01


def lattice(n, dim, spacing=2 * R):
    axes = [np.arange(n) * spacing] * dim
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, dim)


@pytest.mark.parametrize("dim", [2, 3])
def test_sums_equal_a_brute_force_sum_over_every_pair(dim):
    rng = np.random.default_rng(7)
    x = rng.uniform(0, 12 * R, size=(400, dim))
    h = density_audit.SUPPORT * R
    w, c = density_audit.sums(x, h)
    d = x[None, :, :] - x[:, None, :]  # x_j - x_i
    wij = density_audit.cubic_spline(np.linalg.norm(d, axis=2), h, dim)
    np.testing.assert_allclose(w, wij.sum(axis=1), rtol=1e-12)
    np.testing.assert_allclose(c, (wij[:, :, None] * d).sum(axis=1), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
def test_the_kernel_integrates_to_one(dim):
    h, step = 1.0, 0.01
    r = np.arange(step / 2, h, step)
    shell = 2 * math.pi * r if dim == 2 else 4 * math.pi * r * r
    assert (density_audit.cubic_spline(r, h, dim) * shell * step).sum() == pytest.approx(1.0, rel=1e-3)


@pytest.mark.parametrize("dim,n", [(2, 30), (3, 14)])
def test_a_resting_lattice_reads_the_rest_density_inside_and_keeps_only_the_inside(dim, n):
    x = lattice(n, dim)
    mass = density_audit.flowclip_mass(R, dim, 1000.0)
    a = density_audit.audit(x, R, mass, 1000.0)
    # The outer layer sees neighbours on one side only; the next one already
    # has all of its neighbours (the kernel reaches one lattice step).
    assert a["interior"] == (n - 2) ** dim
    assert abs(a["mean_deviation_pct"]) < 1e-9
    assert a["mean_compression_pct"] < 1e-9


@pytest.mark.parametrize("dim,n", [(2, 30), (3, 14)])
def test_a_compressed_lattice_reads_its_compression(dim, n):
    s = 0.99  # spacing, of 2r
    x = lattice(n, dim, spacing=2 * R * s)
    mass = density_audit.flowclip_mass(R, dim, 1000.0)
    # The expected density: one particle's sum over its lattice, by hand.
    h = density_audit.SUPPORT * R
    offsets = lattice(5, dim, spacing=2 * R * s) - 2 * (2 * R * s)
    expected = mass * density_audit.cubic_spline(np.linalg.norm(offsets, axis=1), h, dim).sum() / 1000.0 - 1.0
    assert expected > 0.01  # compressed by more than 1 %
    a = density_audit.audit(x, R, mass, 1000.0)
    assert a["interior"] == (n - 2) ** dim
    # The second layer now misses the outer layer's far side: 1e-5 of it.
    assert a["mean_deviation_pct"] == pytest.approx(100 * expected, rel=1e-4)
    assert a["mean_compression_pct"] == pytest.approx(100 * expected, rel=1e-4)


def write_splishsplash_vtk(path, x):
    """A particle file in the layout SPlisHSPlasH's VTK exporter writes."""
    n = len(x)
    with open(path, "wb") as fh:
        fh.write(b"# vtk DataFile Version 4.1\nSPlisHSPlasH particle data\nBINARY\nDATASET UNSTRUCTURED_GRID\n")
        fh.write(f"POINTS {n} float\n".encode())
        fh.write(np.asarray(x, dtype=">f4").tobytes() + b"\n")
        fh.write(f"CELLS {n} {2 * n}\n".encode())
        fh.write(np.stack([np.ones(n), np.arange(n)], axis=1).astype(">u4").tobytes() + b"\n")
        fh.write(f"CELL_TYPES {n}\n".encode() + np.ones(n, dtype=">i4").tobytes() + b"\n")
        fh.write(f"POINT_DATA {n}\nFIELD FieldData 1\ndensity 1 {n} float\n".encode())
        fh.write(np.full(n, 1000.0, dtype=">f4").tobytes() + b"\n")


def test_splishsplash_files_read_in_frame_order_with_their_times(tmp_path):
    rng = np.random.default_rng(3)
    frames = {k: rng.uniform(-1, 1, size=(50 + k, 3)).astype(np.float32) for k in (1, 2, 9, 10, 11)}
    for k, x in frames.items():
        write_splishsplash_vtk(tmp_path / f"ParticleData_Fluid_{k}.vtk", x)
    got = density_audit.vtk_frames([str(p) for p in tmp_path.iterdir()], fps=20.0, dim=3)
    assert [t for t, _ in got] == [0.0, 0.05, 0.4, 0.45, 0.5]
    for (t, x), k in zip(got, sorted(frames)):
        np.testing.assert_array_equal(x, frames[k].astype(np.float64))


def test_a_file_without_points_is_a_clear_error(tmp_path):
    p = tmp_path / "ParticleData_Fluid_1.vtk"
    p.write_bytes(b"# vtk DataFile Version 4.1\nnothing\n")
    with pytest.raises(ValueError, match="no POINTS"):
        density_audit.read_vtk(str(p))


@pytest.mark.heavy
@pytest.mark.skipif(not FLOWCLIP_BIN.exists(), reason=f"{FLOWCLIP_BIN} does not exist: build it first (make build)")
def test_flowclips_resting_column_holds_its_tolerance_measured_from_its_export(tmp_path):
    scene = json.loads((ROOT / "scenes" / "hydrostatic2d.json").read_text())
    tolerance = scene["solver"]["density_tolerance_pct"]
    out = tmp_path / "column.h5"
    subprocess.run([str(FLOWCLIP_BIN), "run", str(ROOT / "scenes" / "hydrostatic2d.json"), "--frames", "30",
                    "--export", str(out), "--quiet", "--threads", "2"], check=True, cwd=ROOT, timeout=900)
    r, dim, rest, frames = density_audit.read_h5(str(out), every=10)
    assert dim == 2 and len(frames) == 3
    s = density_audit.summarise(frames, r, density_audit.flowclip_mass(r, dim, rest), rest)
    # Most of a column is interior. DFSPH bounds the mean compression over
    # all particles, those by the surface and walls included, which read
    # less: read independently the interior holds about its tolerance
    # (measured 1.02 times), and it is not stretched either.
    assert s["interior_share"] > 0.5
    assert 0 < s["mean_compression_pct"] <= 2 * tolerance
    assert abs(s["mean_deviation_pct"]) <= 2 * tolerance
