#!/usr/bin/env python3
"""`make gallery`: every shipped scene as a short sequence of its surface,
rendered by Blender (Cycles on the CPU, headless), as PNG contact sheets in
docs/images/gallery/ (one per scene, and gallery.png with one frame of each
for the README).

For each scene: the templates its instances play are recorded when missing
(`flowclip record`), the scene runs for its duration with a particle export,
`flowclip export` meshes the frames to show (PLY), and
tools/blender/render_mesh.py renders them from the scene's "camera". This
both makes the pictures and shows that Blender imports FlowClip's meshes.
Only the liquid is drawn (obstacles and bodies are not exported). With
--animate K, K frames through the scene's duration also become an animated
WebP preview, NAME.webp, beside the contact sheet.

    build/venv/bin/python tools/gallery.py [--scenes drop2d,letters3d] [--frames 4] [--animate 24]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FLOWCLIP = ROOT / "build" / "flowclip"
RENDER = ROOT / "tools" / "blender" / "render_mesh.py"
# The twelve scenes of the paper's Table 1 as shipped, then the dam breaks.
SCENES = ["drop2d", "doubledam2d", "wave2d", "waterjet2d", "blade2d", "multiphase2d", "letters3d", "viscous3d",
          "composition3d", "multiphase3d", "blade3d", "boat3d", "dambreak2d", "dambreak3d"]


def log(msg: str) -> None:
    print(msg, flush=True)


def templates_of(scene: dict) -> list[str]:
    return sorted({i["template"] for i in scene.get("instances", []) if "template" in i})


def ensure_templates(names: list[str], threads: int) -> None:
    for name in names:
        if (ROOT / "templates" / f"{name}.h5").exists():
            continue
        recipe = ROOT / "templates" / "recipes" / f"{name}.json"
        if not recipe.exists():  # a recipe may record several templates: the one that names it
            recipe = next((r for r in sorted((ROOT / "templates" / "recipes").glob("*.json"))
                           if f'"{name}"' in r.read_text()), recipe)
        log(f"  recording template {name} ({recipe.name})")
        subprocess.run([str(FLOWCLIP), "record", str(recipe), "--threads", str(threads)], cwd=ROOT, check=True)


def render(ply: Path, png: Path, camera: dict | None, size: tuple[int, int], samples: int) -> None:
    cmd = ["blender", "-b", "--factory-startup", "--python", str(RENDER), "--", "--mesh", str(ply), "--out", str(png),
           "--size", str(size[0]), str(size[1]), "--samples", str(samples)]
    if camera:
        cmd += ["--camera", *map(str, camera["position"]), "--target", *map(str, camera["target"]),
                "--lens", str(camera.get("lens_mm", 40))]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=1800)
    if proc.returncode != 0 or not png.exists():
        sys.exit(f"gallery: Blender failed on {ply}:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}")


def contact_sheet(images: list[Path], labels: list[str], title: str, out: Path, columns: int) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.image as mpimg
    import matplotlib.pyplot as plt

    rows = (len(images) + columns - 1) // columns
    first = mpimg.imread(str(images[0]))
    h, w = first.shape[:2]
    fig = plt.figure(figsize=(columns * w / 100, rows * h / 100 + (0.35 if title else 0)), dpi=100)
    for i, (img, label) in enumerate(zip(images, labels)):
        ax = fig.add_subplot(rows, columns, i + 1)
        ax.imshow(mpimg.imread(str(img)))
        ax.set_axis_off()
        ax.text(0.02, 0.04, label, transform=ax.transAxes, fontsize=9, color="black",
                bbox={"facecolor": "white", "alpha": 0.7, "pad": 2, "linewidth": 0})
    if title:
        fig.suptitle(title, fontsize=11)
    fig.subplots_adjust(left=0, right=1, bottom=0, top=(1 - 0.35 / (rows * h / 100 + 0.35)) if title else 1,
                        wspace=0.01, hspace=0.01)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(str(out))
    plt.close(fig)


def animate(images: list[Path], out: Path, frame_ms: float) -> None:
    """An animated WebP that plays the frames at the scene's speed, looping."""
    from PIL import Image

    frames = [Image.open(str(p)).convert("RGB") for p in images]
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    frames[0].save(str(tmp), format="WEBP", save_all=True, append_images=frames[1:], duration=max(20, round(frame_ms)),
                   loop=0, quality=80, method=4)
    tmp.replace(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--frames", type=int, default=4, help="frames shown per scene")
    ap.add_argument("--size", default="320x200", help="pixels per frame, WxH")
    ap.add_argument("--samples", type=int, default=12, help="Cycles samples per pixel")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--animate", type=int, default=24, help="frames of the animated preview (0: none)")
    ap.add_argument("--animate-samples", type=int, default=6, help="Cycles samples per pixel of its frames")
    ap.add_argument("--reuse-runs", action="store_true",
                    help="use a scene's particle export from an earlier run when the work folder has one")
    ap.add_argument("--work", default=str(ROOT / "build" / "gallery"))
    ap.add_argument("--out", default=str(ROOT / "docs" / "images" / "gallery"))
    a = ap.parse_args()
    if not FLOWCLIP.exists():
        sys.exit(f"gallery: {FLOWCLIP} is missing: make build first")
    if not shutil.which("blender"):
        sys.exit("gallery: blender is missing (make setup installs it)")
    size = tuple(int(v) for v in a.size.split("x"))
    work, out = Path(a.work), Path(a.out)
    work.mkdir(parents=True, exist_ok=True)
    names = [s for s in a.scenes.split(",") if s]
    firsts, first_labels = [], []
    for n, name in enumerate(names, 1):
        t0 = time.monotonic()
        scene_path = ROOT / "scenes" / f"{name}.json"
        scene = json.loads(scene_path.read_text())
        log(f"[{n}/{len(names)}] {name}")
        ensure_templates(templates_of(scene), a.threads)
        h5 = work / f"{name}.h5"
        if not (a.reuse_runs and h5.exists()):
            subprocess.run([str(FLOWCLIP), "run", str(scene_path), "--export", str(h5), "--threads", str(a.threads),
                            "--quiet"], cwd=ROOT, check=True)
        rate = scene.get("settings", {}).get("frame_rate", 60)
        last = int(round(scene.get("duration", 2) * rate))
        mesh_dir = work / name

        def frame_png(f: int, png: Path, samples: int) -> Path:
            subprocess.run([str(FLOWCLIP), "export", str(h5), "--out", str(mesh_dir), "--name", name, "--formats",
                            "ply", "--first", str(f), "--last", str(f), "--threads", str(a.threads), "--quiet"],
                           cwd=ROOT, check=True)
            render(mesh_dir / f"{name}.{f:04d}.ply", png, scene.get("camera"), size, samples)
            return png

        shown = sorted({max(1, round(last * (k + 1) / a.frames)) for k in range(a.frames)})
        images = [frame_png(f, work / f"{name}.{f:04d}.png", a.samples) for f in shown]
        labels = [f"t = {f / rate:.2f} s" for f in shown]
        contact_sheet(images, labels, name, out / f"{name}.png", columns=len(images))
        (work / f"{name}.shown").write_text(images[len(images) // 2].name)
        log(f"  {len(images)} frames in {time.monotonic() - t0:.0f} s -> {out / (name + '.png')}")
        if a.animate > 0:
            t1 = time.monotonic()
            frames = sorted({max(1, round(last * (k + 1) / a.animate)) for k in range(a.animate)})
            pngs = []
            for k, f in enumerate(frames, 1):
                pngs.append(frame_png(f, work / f"{name}.anim.{f:04d}.png", a.animate_samples))
                print(f"\r  animation: frame {k}/{len(frames)}", end="", file=sys.stderr, flush=True)
            print(file=sys.stderr)
            animate(pngs, out / f"{name}.webp", 1000 * last / rate / len(frames))
            log(f"  {len(pngs)} animation frames in {time.monotonic() - t1:.0f} s -> {out / (name + '.webp')}")
    # gallery.png: the middle frame of every scene rendered so far (this run or an earlier one).
    for name in SCENES:
        shown = work / f"{name}.shown"
        if shown.exists() and (work / shown.read_text().strip()).exists():
            firsts.append(work / shown.read_text().strip())
            first_labels.append(name)
    if firsts:
        contact_sheet(firsts, first_labels, "", out / "gallery.png", columns=4)
        log(f"gallery: {out / 'gallery.png'} ({len(firsts)} scenes)")


if __name__ == "__main__":
    main()
