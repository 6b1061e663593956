"""Scenes and recipes at their named resolution ("scales": {"paper": ...}):
`flowclip record --scale paper` records a recipe's template at the paper's
resolution into TEMPLATES/paper, `flowclip run --scale paper` runs the scene
at it with the templates of that folder, and a stopped batch of recordings
resumes (`--skip-existing`). docs/benchmarks/paper-scale.md.
"""
from __future__ import annotations

import json
import re
import subprocess

import pytest

from repo_paths import FLOWCLIP_BIN, ROOT

h5py = pytest.importorskip("h5py")

SCENE = ROOT / "scenes" / "drop2d.json"
RECIPE = ROOT / "templates" / "recipes" / "drop2d.json"
PAPER_LIQUID = 6.7e3  # the paper's Table 1, 2D Rectangular drop


def flowclip(*args, cwd=None, timeout=900):
    return subprocess.run([str(FLOWCLIP_BIN), *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=timeout)


@pytest.fixture(scope="module")
def paper_templates(tmp_path_factory):
    """The drop2d template recorded at the recipe's paper scale (tmp/templates/paper)."""
    root = tmp_path_factory.mktemp("paper")
    proc = flowclip("record", RECIPE, "--scale", "paper", "--quiet", "--threads", 2, cwd=root)
    assert proc.returncode == 0, proc.stderr
    return root / "templates" / "paper"


@pytest.mark.heavy
def test_record_at_the_recipes_paper_resolution(paper_templates):
    recipe = json.loads(RECIPE.read_text())
    path = paper_templates / "drop2d.h5"
    assert path.exists(), sorted(p.name for p in paper_templates.parent.rglob("*"))
    with h5py.File(path, "r") as f:
        assert f.attrs["particle_radius"] == pytest.approx(recipe["scales"]["paper"]["particle_radius"], rel=1e-6)
        assert f.attrs["particle_radius"] < recipe["particle_radius"]


@pytest.mark.heavy
def test_a_recorded_template_is_kept_and_a_missing_one_recorded(paper_templates, tmp_path):
    before = (paper_templates / "drop2d.h5").stat()
    proc = flowclip("record", RECIPE, "--scale", "paper", "--skip-existing", "--templates", paper_templates)
    assert proc.returncode == 0, proc.stderr
    assert "already" in proc.stderr
    after = (paper_templates / "drop2d.h5").stat()
    assert (after.st_mtime_ns, after.st_ino) == (before.st_mtime_ns, before.st_ino), "the template was rewritten"
    # Without it, an existing template is refused rather than overwritten.
    proc = flowclip("record", RECIPE, "--scale", "paper", "--templates", paper_templates)
    assert proc.returncode != 0 and "--force" in proc.stderr


def run_stats(tmp_path, name, *args):
    stats = tmp_path / f"{name}.json"
    proc = flowclip("run", SCENE, "--frames", 3, "--threads", 1, "--quiet", "--stats", stats, *args)
    assert proc.returncode == 0, proc.stderr
    return json.loads(stats.read_text())


@pytest.mark.heavy
def test_run_at_the_paper_scale_holds_the_papers_liquid(paper_templates, tmp_path):
    scene = json.loads(SCENE.read_text())
    radius = scene["scales"]["paper"]["particle_radius"]
    scaled = run_stats(tmp_path, "scaled", "--scale", "paper", "--templates", paper_templates)
    liquid = [f["particles"] - f.get("temporary_particles", 0) for f in scaled["frames"]]
    assert liquid[0] == pytest.approx(PAPER_LIQUID, rel=0.1)
    shipped = run_stats(tmp_path, "shipped", "--templates", ROOT / "templates")["frames"][0]
    assert liquid[0] > 2 * (shipped["particles"] - shipped.get("temporary_particles", 0))
    # The same run as the scene with --particle-radius at the scale's value.
    plain = run_stats(tmp_path, "plain", "--particle-radius", radius, "--templates", paper_templates)
    keys = ("particles", "temporary_particles", "substeps", "divergence_iterations", "density_iterations",
            "avg_density_error_pct", "control_particles")
    for a, b in zip(scaled["frames"], plain["frames"]):
        assert {k: a.get(k) for k in keys} == {k: b.get(k) for k in keys}


def test_the_scale_looks_for_its_own_templates(tmp_path):
    # No templates/paper under the working directory: the run names the folder it looked in.
    proc = flowclip("run", SCENE, "--scale", "paper", "--frames", 1, "--quiet", cwd=tmp_path)
    assert proc.returncode != 0
    assert "templates/paper" in proc.stderr, proc.stderr


def test_a_scale_that_names_its_templates_folder_plays_and_records_there(tmp_path):
    # The boat's paper scale plays a hand recorded at its own resolution, from templates/paper-boat.
    scene = json.loads(SCENE.read_text())
    scene["scales"]["paper"]["templates"] = "paper-x"
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(scene))
    proc = flowclip("run", path, "--scale", "paper", "--frames", 1, "--quiet", cwd=tmp_path)
    assert proc.returncode != 0
    assert "templates/paper-x" in proc.stderr, proc.stderr
    # A recipe's scale records into the folder it names, which the scene's scale then plays.
    recipe = json.loads(RECIPE.read_text())
    recipe["scales"]["coarse"] = {"particle_radius": 2 * recipe["particle_radius"], "templates": "paper-x"}
    recipe["capture"]["seconds"] = 0.05
    rpath = tmp_path / "recipe.json"
    rpath.write_text(json.dumps(recipe))
    proc = flowclip("record", rpath, "--scale", "coarse", "--quiet", "--threads", 1, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    made = sorted(p.relative_to(tmp_path).as_posix() for p in (tmp_path / "templates").rglob("*.h5"))
    assert made == [f"templates/paper-x/{recipe['capture']['name']}.h5"]
    with h5py.File(tmp_path / made[0], "r") as f:
        assert f.attrs["particle_radius"] == pytest.approx(2 * recipe["particle_radius"], rel=1e-6)
    # A folder that is not one plain name is refused before anything runs.
    scene["scales"]["paper"]["templates"] = "../elsewhere"
    path.write_text(json.dumps(scene))
    proc = flowclip("run", path, "--scale", "paper", "--frames", 1, "--quiet", cwd=tmp_path)
    assert proc.returncode == 2 and "scales.paper.templates" in proc.stderr, proc.stderr


def test_an_unknown_scale_is_refused_naming_the_known_ones(tmp_path):
    proc = flowclip("run", SCENE, "--scale", "final", "--frames", 1, "--quiet", cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "scales.final" in proc.stderr and "paper" in proc.stderr
    proc = flowclip("run", SCENE, "--scale", "paper", "--particle-radius", 0.01, "--frames", 1)
    assert proc.returncode != 0 and "excludes" in proc.stderr


def test_every_table1_scene_and_its_recipes_have_the_paper_scale():
    table1 = ["drop2d", "wave2d", "blade2d", "waterjet2d", "zero_gravity2d", "doubledam2d", "viscous3d", "blade3d",
              "letters3d", "multiphase3d", "boat3d", "composition3d"]
    makefile = (ROOT / "Makefile").read_text()
    recorded = [(name, "paper") for name in
                next(line for line in makefile.splitlines() if line.startswith("RECIPES_PAPER")).split("=")[1].split()]
    # and the recipes it records at a scale of their own (the boat's hand)
    recorded += re.findall(r"record templates/recipes/([a-z0-9_]+)\.json --scale ([a-z0-9_-]+)", makefile)
    captured = {}  # (template, folder) -> recipe
    for name, scale in recorded:
        recipe = json.loads((ROOT / "templates" / "recipes" / f"{name}.json").read_text())
        assert scale in recipe.get("scales", {}), f"recipe {name} has no scale {scale}"
        folder = recipe["scales"][scale].get("templates", scale)
        caps = recipe["capture"] if isinstance(recipe["capture"], list) else [recipe["capture"]]
        for c in caps:
            captured[(c["name"], folder)] = name
    for name in table1:
        scene = json.loads((ROOT / "scenes" / f"{name}.json").read_text())
        assert "paper" in scene.get("scales", {}), f"scene {name} has no paper scale"
        folder = scene["scales"]["paper"].get("templates", "paper")
        for inst in scene.get("instances", []):
            if "template" in inst:
                assert (inst["template"], folder) in captured, \
                    f"{name} plays {inst['template']} from templates/{folder}, which make templates-paper does not record"
    assert json.loads((ROOT / "scenes" / "boat3d.json").read_text())["scales"]["paper"]["templates"] == "paper-boat"


# The 2D scenes of Table 1 and the recipe each plays.
TABLE1_2D = {"drop2d": "drop2d", "wave2d": "wave2d", "blade2d": "blade2d", "waterjet2d": "waterjet2d",
             "zero_gravity2d": "jet2d", "doubledam2d": "doubledam2d"}


@pytest.mark.heavy
def test_the_2d_scenes_at_the_paper_scale_play_the_papers_control_particles(tmp_path):
    """Each recipe's paper radius gives its scene the paper's Control column (the particles its
    template stores per frame, as the paper counts them) within 10 %, and the bench's report
    holds the template storage at most a quarter of the paper's Storage column."""
    templates = tmp_path / "templates"
    for recipe in sorted(set(TABLE1_2D.values())):
        proc = flowclip("record", ROOT / "templates" / "recipes" / f"{recipe}.json", "--scale", "paper",
                        "--templates", templates, "--quiet", "--threads", 2)
        assert proc.returncode == 0, proc.stderr
    out = tmp_path / "bench"
    proc = flowclip("bench", "scenes", "--scale", "paper", "--templates", templates, "--frames", 60, "--threads", 2,
                    "--out", out, *(ROOT / "scenes" / f"{s}.json" for s in TABLE1_2D), timeout=1800)
    assert proc.returncode == 0, proc.stderr
    report = json.loads((out / "scenes.json").read_text())
    assert report["failures"] == []
    rows = {r["scene"]: r for r in report["scenes"]}
    assert set(rows) == set(TABLE1_2D)
    for name, r in rows.items():
        paper = r["paper"]
        assert r["control"] == pytest.approx(paper["control"], rel=0.1), name
        assert r["liquid"] == pytest.approx(paper["liquid"], rel=0.1), name
        assert 0 < r["template_storage_mb"] <= 0.25 * paper["template_storage_mb"], name
    # The ratio table names the control column.
    assert "| scene | liquid | control | ms / frame |" in (out / "scenes.md").read_text()
