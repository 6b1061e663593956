"""Template files written by the C++ writer (server/io/template_file.cpp) open
in h5py and follow the layout documented in templates/README.md.

The files come from the gtest `TemplateFileSample.WriteForH5py`, run here on
its own with FLOWCLIP_TEMPLATE_SAMPLE_DIR pointing at a temporary directory:
it writes sample2d.h5 / sample3d.h5 (a sloshing two-phase blob, 8 frames,
one empty) plus a JSON file with what the C++ `readTemplate` returns for each.
The README's h5py snippet must decode the same values.
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
TESTS = BUILD / "flowclip_tests"
README = ROOT / "templates" / "README.md"

pytestmark = pytest.mark.skipif(
    not TESTS.exists(), reason=f"{TESTS} does not exist: build it first (make build)"
)

STRING_ATTRS = ["format", "name", "recipe", "created_by", "position_encoding",
                "velocity_encoding", "mass_encoding"]
INT_ATTRS = ["format_version", "dimension", "frame_count", "velocity_levels"]
FLOAT_ATTRS = ["frame_rate", "duration", "particle_radius", "support_radius", "rest_density"]


@pytest.fixture(scope="module")
def sample_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("templates")
    cmd = [str(TESTS), "--gtest_filter=TemplateFileSample.*"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "FLOWCLIP_TEMPLATE_SAMPLE_DIR": str(out)})
    assert proc.returncode == 0, f"{' '.join(cmd)} exited with {proc.returncode}:\n{proc.stdout}\n{proc.stderr}"
    for stem in ("sample2d", "sample3d"):
        assert (out / f"{stem}.h5").exists() and (out / f"{stem}.json").exists(), proc.stdout
    return out


@pytest.fixture(scope="module", params=["sample2d", "sample3d"])
def sample(request, sample_dir):
    path = sample_dir / f"{request.param}.h5"
    expected = json.loads((sample_dir / f"{request.param}.json").read_text())
    return path, expected


def test_only_final_files_are_left(sample_dir):
    # Published by rename: no "<name>.tmp-<pid>-<n>" remains.
    assert sorted(p.name for p in sample_dir.iterdir()) == [
        "sample2d.h5", "sample2d.json", "sample3d.h5", "sample3d.json"]


def test_root_attributes(sample):
    path, expected = sample
    with h5py.File(path, "r") as h5:
        a = h5.attrs
        for name in STRING_ATTRS:
            assert isinstance(a[name], str), f"attribute {name} is not a string"
        for name in INT_ATTRS:
            v = np.asarray(a[name])
            assert v.dtype.kind == "i" and v.shape == (), name
        for name in FLOAT_ATTRS:
            v = np.asarray(a[name])
            assert v.dtype == np.float64 and v.shape == () and np.isfinite(v), name
        assert a["format"] == "flowclip-template"
        assert a["format_version"] == 1
        D = int(a["dimension"])
        assert D == (2 if path.stem == "sample2d" else 3)
        F = int(a["frame_count"])
        assert F == len(expected["frames"])
        assert np.isclose(a["duration"], (F - 1) / a["frame_rate"])
        for name in ("region_min", "region_max"):
            v = np.asarray(a[name])
            assert v.dtype == np.float64 and v.shape == (D,), name
        assert np.all(a["region_min"] <= a["region_max"])
        json.loads(a["recipe"])  # the recipe is JSON text
        assert a["position_encoding"] in ("uint16", "float32")
        if a["position_encoding"] == "uint16":
            for name in ("position_origin", "position_step"):
                v = np.asarray(a[name])
                assert v.dtype == np.float64 and v.shape == (D,), name
            # the documented error bound: half a step <= 1 % of the radius
            assert np.all(a["position_step"] / 2 <= 0.01 * a["particle_radius"])
        assert a["velocity_encoding"] == "int16_frame_scale"
        assert a["mass_encoding"] in ("table", "float64")
        if a["mass_encoding"] == "table":
            t = np.asarray(a["mass_table"])
            assert t.dtype == np.float64 and 1 <= len(t) <= 256 and np.all(np.diff(t) > 0)


def test_datasets(sample):
    path, _ = sample
    with h5py.File(path, "r") as h5:
        a = h5.attrs
        D, F = int(a["dimension"]), int(a["frame_count"])
        N = h5["particles/phase"].shape[0]
        pos = "<u2" if a["position_encoding"] == "uint16" else "<f4"
        mass = ("particles/mass_index", "|u1") if a["mass_encoding"] == "table" else ("particles/mass", "<f8")
        spec = {
            "frames/offset": ("<u8", (F + 1,)),
            "frames/velocity_scale": ("<f8", (F,)),
            "particles/position": (pos, (N, D)),
            "particles/velocity": ("<i2", (N, D)),
            mass[0]: (mass[1], (N,)),
            "particles/phase": ("|u1", (N,)),
        }
        for name, (dtype, shape) in spec.items():
            assert name in h5, f"missing dataset /{name}"
            ds = h5[name]
            assert ds.dtype == np.dtype(dtype), f"/{name} is {ds.dtype}, expected {dtype}"
            assert ds.shape == shape, f"/{name} has shape {ds.shape}, expected {shape}"
            assert ds.chunks is not None and ds.compression == "gzip", f"/{name} is not chunked + deflated"
            assert ds.shuffle == (ds.dtype.itemsize > 1), f"/{name}: shuffle only for multi-byte types"
            assert ds.maxshape[0] is None, f"/{name} is not extendible"
        off = h5["frames/offset"][:]
        assert off[0] == 0 and np.all(np.diff(off.astype(np.int64)) >= 0) and off[-1] == N
        assert np.any(np.diff(off) == 0), "the sample has an empty frame"
        scale = h5["frames/velocity_scale"][:]
        assert np.all(np.isfinite(scale)) and np.all(scale >= 0)
        assert np.abs(h5["particles/velocity"][:]).max() <= a["velocity_levels"]
        if a["mass_encoding"] == "table":
            assert h5["particles/mass_index"][:].max() < len(a["mass_table"])


def test_documented_snippet_decodes_like_the_cpp_reader(sample):
    path, expected = sample
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    assert blocks, "templates/README.md has no python snippet"
    snippet = blocks[0]
    assert '"blob.h5"' in snippet
    env = {}
    exec(snippet.replace('"blob.h5"', repr(str(path))), env)
    load_frame = env["load_frame"]
    for f, fr in enumerate(expected["frames"]):
        x, v, m, phase = load_frame(str(path), f)
        n = len(fr["mass"])
        assert len(x) == n, f"frame {f}: {len(x)} particles, the C++ reader has {n}"
        if n == 0:
            continue
        # The C++ reader returns single-precision values of the same decoding.
        np.testing.assert_allclose(x, fr["x"], rtol=0, atol=1e-6, err_msg=f"positions, frame {f}")
        np.testing.assert_allclose(v, fr["v"], rtol=1e-6, atol=1e-9, err_msg=f"velocities, frame {f}")
        np.testing.assert_allclose(m, fr["mass"], rtol=1e-7, err_msg=f"masses, frame {f}")
        np.testing.assert_array_equal(phase, fr["phase"], err_msg=f"phases, frame {f}")
