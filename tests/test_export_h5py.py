"""`flowclip run --export` writes the documented HDF5 frame file (docs/export-format.md).

Runs the hydrostatic 2D scene for 3 frames with export and checks the file
with h5py against the layout contract: attributes, dataset dtypes and shapes,
ragged frame offsets, finite positions inside the domain, frame times.
"""
import json
import os
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

h5py = pytest.importorskip("h5py")

ROOT = Path(__file__).resolve().parents[1]
BUILD = Path(os.environ.get("FLOWCLIP_BUILD_DIR", ROOT / "build"))
FLOWCLIP = BUILD / "flowclip"
SCENE = ROOT / "scenes" / "hydrostatic2d.json"
FRAMES = 3

pytestmark = pytest.mark.skipif(
    not FLOWCLIP.exists(), reason=f"{FLOWCLIP} does not exist: build it first (make build)"
)

ROOT_ATTRS = [
    "format", "format_version", "dimension", "scene", "particle_radius", "frame_rate",
    "domain_min", "domain_max", "created_by", "phase_names", "phase_rest_density",
]
# name -> (dtype, columns: None for one-dimensional, "D" for the dimension)
FRAME_DATASETS = {
    "frames/index": ("<u4", None),
    "frames/time": ("<f8", None),
    "frames/offset": ("<u8", None),
    "frames/count": ("<u4", None),
}
PARTICLE_DATASETS = {
    "particles/position": ("<f4", "D"),
    "particles/velocity": ("<f4", "D"),
    "particles/density": ("<f4", None),
    "particles/pressure": ("<f4", None),
    "particles/phase": ("|u1", None),
    "particles/kind": ("|u1", None),
    "particles/id": ("<u4", None),
}


@pytest.fixture(scope="module")
def export_dir(tmp_path_factory):
    out_dir = tmp_path_factory.mktemp("export")
    out = out_dir / "out.h5"
    cmd = [str(FLOWCLIP), "run", str(SCENE), "--frames", str(FRAMES), "--export", str(out), "--quiet"]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, f"{' '.join(cmd)} exited with {proc.returncode}:\n{proc.stderr}"
    assert out.exists(), f"{' '.join(cmd)} succeeded but wrote no {out}"
    return out_dir


@pytest.fixture(scope="module")
def h5(export_dir):
    with h5py.File(export_dir / "out.h5", "r") as f:
        yield f


@pytest.fixture(scope="module")
def scene():
    return json.loads(SCENE.read_text())


def frame_rows(h5):
    offset = h5["frames/offset"][:]
    return [(int(a), int(b)) for a, b in zip(offset[:-1], offset[1:])]


def test_only_the_final_file_is_left(export_dir):
    # Published by rename: no temporary "<path>.tmp-<pid>" remains.
    assert sorted(p.name for p in export_dir.iterdir()) == ["out.h5"]


def test_root_attributes(h5, scene):
    missing = [a for a in ROOT_ATTRS if a not in h5.attrs]
    assert not missing, f"missing root attributes: {missing}"
    a = h5.attrs
    assert a["format"] == "flowclip-frames"
    assert np.asarray(a["format_version"]).dtype.kind == "i" and a["format_version"] == 1
    assert np.asarray(a["dimension"]).dtype.kind == "i" and a["dimension"] == scene["dimension"]
    assert isinstance(a["scene"], str) and a["scene"] == scene.get("name", a["scene"])
    assert isinstance(a["created_by"], str) and a["created_by"]
    for name in ("particle_radius", "frame_rate"):
        v = np.asarray(a[name])
        assert v.dtype == np.float64 and v.shape == () and v > 0, name
    D = int(a["dimension"])
    for name in ("domain_min", "domain_max"):
        v = np.asarray(a[name])
        assert v.dtype == np.float64 and v.shape == (D,), name
    np.testing.assert_allclose(a["domain_min"], scene["domain"]["min"])
    np.testing.assert_allclose(a["domain_max"], scene["domain"]["max"])
    names = [str(n) for n in np.atleast_1d(a["phase_names"])]
    rho = np.asarray(a["phase_rest_density"])
    assert rho.dtype == np.float64 and rho.shape == (len(names),) and len(names) >= 1
    assert names == [p["name"] for p in scene["phases"]]
    np.testing.assert_allclose(rho, [p["rest_density"] for p in scene["phases"]])


def test_dataset_dtypes_and_shapes(h5):
    D = int(h5.attrs["dimension"])
    F = h5["frames/index"].shape[0]
    N = h5["particles/id"].shape[0]
    for name, (dtype, cols) in {**FRAME_DATASETS, **PARTICLE_DATASETS}.items():
        assert name in h5, f"missing dataset /{name}"
        ds = h5[name]
        assert ds.dtype == np.dtype(dtype), f"/{name} is {ds.dtype}, expected {dtype}"
        rows = F + 1 if name == "frames/offset" else F if name.startswith("frames/") else N
        shape = (rows, D) if cols == "D" else (rows,)
        assert ds.shape == shape, f"/{name} has shape {ds.shape}, expected {shape}"
        assert ds.maxshape[0] is None, f"/{name} is not extendible"
        assert ds.chunks is not None and ds.compression == "gzip", f"/{name} is not chunked + deflated"


def test_frame_count(h5):
    # --frames 3: three simulated frames, plus the initial state at t = 0 if
    # `run` exports it (it writes frame 0 before the first step).
    F = h5["frames/index"].shape[0]
    assert F in (FRAMES, FRAMES + 1), f"{F} frames for --frames {FRAMES}"
    if F == FRAMES + 1:
        assert h5["frames/time"][0] == 0.0


def test_offsets_are_consistent(h5):
    offset = h5["frames/offset"][:]
    count = h5["frames/count"][:]
    assert offset[0] == 0
    assert np.all(np.diff(offset.astype(np.int64)) >= 0)
    np.testing.assert_array_equal(np.diff(offset), count)
    assert offset[-1] == h5["particles/id"].shape[0]
    assert np.all(count > 0), "a frame of the hydrostatic scene without particles"


def test_positions_finite_and_inside_domain(h5):
    lo = np.asarray(h5.attrs["domain_min"])
    hi = np.asarray(h5.attrs["domain_max"])
    eps = 1e-6 * float(np.max(hi - lo))  # float32 rounding of positions
    for f, (a, b) in enumerate(frame_rows(h5)):
        x = h5["particles/position"][a:b]
        assert np.all(np.isfinite(x)), f"non-finite position in frame {f}"
        outside = np.any((x < lo - eps) | (x > hi + eps), axis=1)
        assert not outside.any(), (
            f"frame {f}: {int(outside.sum())} particles outside the domain {lo}..{hi}, "
            f"e.g. {x[outside][:3].tolist()}")


def test_frame_times_step_by_one_frame(h5):
    time = h5["frames/time"][:]
    index = h5["frames/index"][:].astype(np.int64)
    rate = float(h5.attrs["frame_rate"])
    assert len(time) >= 2
    np.testing.assert_allclose(np.diff(time), 1.0 / rate, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(np.diff(index), 1)


def test_particle_columns(h5):
    n_phases = len(np.atleast_1d(h5.attrs["phase_names"]))
    for f, (a, b) in enumerate(frame_rows(h5)):
        for name in ("velocity", "density", "pressure"):
            v = h5[f"particles/{name}"][a:b]
            assert np.all(np.isfinite(v)), f"non-finite {name} in frame {f}"
        assert np.all(h5["particles/phase"][a:b] < n_phases), f"phase index out of range in frame {f}"
        assert set(np.unique(h5["particles/kind"][a:b])) <= {0, 1, 2}, f"unknown kind in frame {f}"
        ids = h5["particles/id"][a:b]
        assert len(np.unique(ids)) == len(ids), f"duplicate particle id in frame {f}"


def test_documented_snippet_loads_a_frame(export_dir, h5):
    # The h5py snippet in docs/export-format.md is part of the contract.
    doc = (ROOT / "docs" / "export-format.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", doc, re.S)
    assert blocks, "docs/export-format.md has no python snippet"
    snippet = blocks[0]
    assert '"out.h5"' in snippet
    f = 1
    env = {"f": f}
    exec(snippet.replace('"out.h5"', repr(str(export_dir / "out.h5"))), env)
    a, b = frame_rows(h5)[f]
    np.testing.assert_array_equal(env["pos"], h5["particles/position"][a:b])
    np.testing.assert_array_equal(env["ids"], h5["particles/id"][a:b])
    assert env["t"] == h5["frames/time"][f]
