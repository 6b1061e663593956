#!/usr/bin/env python3
"""The density of a liquid measured from its exported particle positions
alone, with its own SPH sums (numpy only): neither solver's estimate is read.
For FlowClip's HDF5 exports and SPlisHSPlasH's VTK ones, so that both codes'
frames are measured by one piece of code (tools/bench_reference.py).

    build/venv/bin/python tools/density_audit.py out.h5 --every 6
    build/venv/bin/python tools/density_audit.py 'vtk/*.vtk' --radius 0.01 --mass 0.008 --fps 10

Each particle's density is rho_i = m sum_j W(|x_i - x_j|) over the liquid's
particles with the cubic spline of support 4r (both codes' kernel and
support). Its mass is the code's own: FlowClip's makes its initial lattice
(spacing 2r) read exactly the rest density (`flowclip_mass`); SPlisHSPlasH's
is what it reports (2.19: (2r)^D rho0, within 0.003 % of FlowClip's), given
with --mass. Only interior particles are counted: those whose
kernel-weighted neighbour centroid lies within `CENTROID_LIMIT` radii of
the particle. Near a wall (whose own contribution to the density is not in
the files) and near the free surface the neighbours lie on one side and the
centroid moves off by a large part of a radius; inside, where compression
is measured, it stays near the particle whatever the density.

Figures per frame: the interior's mean relative deviation from the rest
density (signed), its mean compression (the positive part, what DFSPH's
tolerance bounds), its 99th percentile, and how many particles are interior.
"""
import argparse
import glob
import json
import math
import re
import sys

import numpy as np

# An interior particle's neighbour centroid is within this many radii of it.
CENTROID_LIMIT = 0.05
SUPPORT = 4.0  # kernel support, in particle radii


def cubic_spline(dist, h, dim):
    """The cubic spline W(r) of support h (SPlisHSPlasH's CubicKernel and
    FlowClip's CubicSpline), at the distances `dist`."""
    k = 40.0 / (7.0 * math.pi * h * h) if dim == 2 else 8.0 / (math.pi * h ** 3)
    q = dist / h
    w = np.where(q <= 0.5, 6.0 * q ** 3 - 6.0 * q ** 2 + 1.0, 2.0 * np.clip(1.0 - q, 0.0, None) ** 3)
    return k * np.where(q <= 1.0, w, 0.0)


def lattice_volume(radius, dim):
    """FlowClip's particle volume: the inverse of the kernel's sum over a
    square (cubic) lattice of spacing 2r around one point."""
    h, s = SUPPORT * radius, 2.0 * radius
    n = int(math.ceil(h / s))
    axes = [np.arange(-n, n + 1) * s] * dim
    offsets = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, dim)
    return 1.0 / float(cubic_spline(np.linalg.norm(offsets, axis=1), h, dim).sum())


def flowclip_mass(radius, dim, rest_density):
    """FlowClip's particle mass: the rest density times the lattice volume."""
    return rest_density * lattice_volume(radius, dim)


def sums(x, h):
    """For every particle of `x` (N x D): sum_j W_ij and sum_j W_ij (x_j - x_i)
    over the particles within h (itself included), by a grid of cells h wide."""
    n, dim = x.shape
    cell = np.floor((x - x.min(axis=0)) / h).astype(np.int64)
    shape = cell.max(axis=0) + 3  # a ring of empty cells around the particles
    cell += 1
    flat = np.ravel_multi_index(cell.T, shape)
    order = np.argsort(flat, kind="stable")
    xs, fs = x[order], flat[order]
    start = np.searchsorted(fs, np.arange(int(np.prod(shape)) + 1))
    count = np.diff(start)
    strides = np.array([int(np.prod(shape[d + 1:])) for d in range(dim)])
    w_sum = np.zeros(n)
    c_sum = np.zeros((n, dim))
    for offset in np.stack(np.meshgrid(*[[-1, 0, 1]] * dim, indexing="ij"), axis=-1).reshape(-1, dim):
        other = fs + int(offset @ strides)
        first, many = start[other], count[other]
        for slot in range(int(many.max(initial=0))):
            has = slot < many
            i = np.nonzero(has)[0]
            d = xs[first[i] + slot] - xs[i]
            w = cubic_spline(np.sqrt((d * d).sum(axis=1)), h, dim)
            w_sum[i] += w
            c_sum[i] += w[:, None] * d
    back = np.empty(n, dtype=np.int64)
    back[order] = np.arange(n)
    return w_sum[back], c_sum[back]


def audit(x, radius, mass, rest_density):
    """The figures of one frame's liquid positions x (N x D)."""
    w, c = sums(np.asarray(x, dtype=np.float64), SUPPORT * radius)
    rho = mass * w
    centroid = np.linalg.norm(c / w[:, None], axis=1) / radius
    inner = centroid < CENTROID_LIMIT
    dev = rho[inner] / rest_density - 1.0
    if dev.size == 0:
        return {"particles": int(len(x)), "interior": 0}
    return {"particles": int(len(x)), "interior": int(dev.size),
            "mean_deviation_pct": float(100 * dev.mean()),
            "mean_compression_pct": float(100 * np.clip(dev, 0, None).mean()),
            "p99_compression_pct": float(100 * np.percentile(dev, 99))}


def read_h5(path, every=1):
    """FlowClip's export: (radius, dimension, rest density, [(time, liquid positions)])."""
    import h5py
    with h5py.File(path, "r") as f:
        radius, dim = float(f.attrs["particle_radius"]), int(f.attrs["dimension"])
        rest = float(np.asarray(f.attrs["phase_rest_density"]).ravel()[0])
        times, offsets, counts = f["frames/time"][:], f["frames/offset"][:], f["frames/count"][:]
        frames = []
        # Frame 0 is the state at t = 0; every n-th after it, at n / frame rate, 2n / frame rate, ...
        for k in range(every, len(times), every):
            a, b = int(offsets[k]), int(offsets[k] + counts[k])
            kind = f["particles/kind"][a:b]
            frames.append((float(times[k]), f["particles/position"][a:b][kind <= 1]))
    return radius, dim, rest, frames


def _vtk_vectors(path, header, what):
    """The 3-vectors that follow the line `header` (a regex whose groups are the count and float|double) in a
    legacy binary VTK file (SPlisHSPlasH's particle export: big-endian)."""
    with open(path, "rb") as fh:
        data = fh.read()
    m = re.search(header, data)
    if not m:
        raise ValueError(f"{path}: no {what} in this VTK file")
    n, kind = int(m.group(1)), m.group(2)
    dtype = ">f4" if kind == b"float" else ">f8"
    return np.frombuffer(data, dtype=dtype, count=3 * n, offset=m.end()).reshape(n, 3).astype(np.float64)


def read_vtk(path):
    """The POINTS of a legacy binary VTK file (SPlisHSPlasH's particle export: big-endian)."""
    return _vtk_vectors(path, rb"POINTS (\d+) (float|double)\n", "POINTS")


def read_vtk_field(path, name):
    """A 3-component array of the file's FIELD data (SPlisHSPlasH's `particleAttributes`, e.g. velocity)."""
    return _vtk_vectors(path, rb"\n" + re.escape(name.encode()) + rb" 3 (\d+) (float|double)\n",
                        f"{name} array (export with particleAttributes {name})")


def vtk_frames(files, fps, dim, read=read_vtk):
    """[(time, read(file)[:, :dim])] of SPlisHSPlasH's files ParticleData_<model>_<frame>.vtk, frame 1 at t = 0."""
    def number(p):
        return int(re.search(r"_(\d+)\.vtk$", p).group(1))
    out = []
    for p in sorted(files, key=number):
        x = read(p)
        out.append(((number(p) - 1) / fps, x[:, :dim]))
    return out


def summarise(frames, radius, mass, rest):
    """Each frame's figures, and their means over the frames."""
    per = [{"time": t, **audit(x, radius, mass, rest)} for t, x in frames]
    keys = ["mean_deviation_pct", "mean_compression_pct", "p99_compression_pct"]
    counted = [f for f in per if f["interior"] > 0]
    means = {k: (sum(f[k] for f in counted) / len(counted) if counted else float("nan")) for k in keys}
    means["interior_share"] = (sum(f["interior"] for f in per) / max(1, sum(f["particles"] for f in per)))
    means["max_mean_compression_pct"] = max((f["mean_compression_pct"] for f in counted), default=float("nan"))
    return {"frames": per, **means, "mass": mass, "centroid_limit_r": CENTROID_LIMIT}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="+", help="one FlowClip .h5 export, or SPlisHSPlasH .vtk files")
    ap.add_argument("--mass", type=float, help="particle mass, kg (default FlowClip's: the rest density times the lattice volume)")
    ap.add_argument("--radius", type=float, help="particle radius, m (VTK files; an .h5 carries its own)")
    ap.add_argument("--rest-density", type=float, default=1000.0, help="kg/m^D (VTK files)")
    ap.add_argument("--dimension", type=int, default=3, choices=(2, 3), help="VTK files")
    ap.add_argument("--fps", type=float, default=60.0, help="the VTK files' export rate (their times)")
    ap.add_argument("--every", type=int, default=1, help="an .h5 export: every n-th frame")
    args = ap.parse_args()
    if len(args.files) == 1 and args.files[0].endswith(".h5"):
        radius, dim, rest, frames = read_h5(args.files[0], args.every)
    else:
        if args.radius is None:
            ap.error("VTK files need --radius")
        radius, dim, rest = args.radius, args.dimension, args.rest_density
        frames = vtk_frames([f for p in args.files for f in glob.glob(p)], args.fps, dim)
    mass = args.mass if args.mass is not None else flowclip_mass(radius, dim, rest)
    if not frames:
        ap.error("no frames in " + " ".join(args.files))
    print(json.dumps(summarise(frames, radius, mass, rest), indent=1))


if __name__ == "__main__":
    sys.exit(main())
