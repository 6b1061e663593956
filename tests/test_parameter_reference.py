"""The docs' parameter reference is generated from the declarations: every
parameter the server declares appears with its type, range and default, and
`flowclip params` answers what GET /api/parameters does."""

from __future__ import annotations

import importlib.util
import json
import re
import subprocess

import requests

from repo_paths import FLOWCLIP_BIN as BIN, ROOT


def _hook():
    spec = importlib.util.spec_from_file_location("parameter_reference", ROOT / "docs" / "hooks" / "parameter_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _params(*args) -> dict:
    return json.loads(subprocess.run([str(BIN), "params", *args], check=True, capture_output=True, text=True).stdout)


def _row(page: str, name: str) -> list[str]:
    rows = [line for line in page.splitlines() if line.startswith(f"| `{name}` |")]
    assert rows, f"{name} has no row in the reference"
    return [c.strip() for c in rows[0].strip("|").split(" | ")]


def test_every_declared_parameter_has_its_row():
    ref = _params()
    hook = _hook()
    page = hook.render(ref)
    sections = [ref["2"]["settings"], ref["2"]["control"], ref["2"]["instance"], ref["2"]["surface"]]
    sections += [e["params"] for e in ref["2"]["solvers"].values()] + [e["params"] for e in ref["2"]["effects"].values()] + [
        e["params"] for e in ref["2"]["boundaries"].values()] + [e["params"] for e in ref["2"]["exporters"].values()]
    assert sum(len(s) for s in sections) > 30
    for specs in sections:
        for spec in specs:
            assert any(line.startswith(f"| `{spec['name']}` | {spec['type']} |") for line in page.splitlines()), spec["name"]
            if spec["type"] != "boolean":
                assert f"[{hook._num(spec['min'])}, {hook._num(spec['max'])}]" in page, spec["name"]
    for name in (list(ref["2"]["solvers"]) + list(ref["2"]["effects"]) + list(ref["2"]["boundaries"]) +
                 list(ref["2"]["exporters"])):
        assert f"### `{name}`" in page
    for lim in ref["2"]["limits"]:
        assert f"| `{lim['name']}` |" in page


def test_defaults_that_differ_by_dimension_show_both():
    page = _hook().render(_params())
    # The paper's weights (§4): 0.2 in 2D, 0.06 in 3D.
    assert _row(page, "attraction_weight")[4] == "0.2 / 0.06 (2D / 3D)"
    assert _row(page, "falloff_width")[4] == "0.05"
    assert _row(page, "cfl_factor")[1:5] == ["number", "", "[0.01, 2]", "1"]
    assert _row(page, "max_substeps_per_frame")[1:5] == ["integer", "", "[10, 1e7]", "10000"]
    assert _row(page, "warm_start")[1] == "boolean"


def test_params_command_answers_what_the_server_does(server):
    for d in (2, 3):
        served = requests.get(f"{server.url}/api/parameters", params={"dimension": d}, timeout=30).json()
        assert _params("--dimension", str(d)) == served


def test_the_scene_reference_holds_no_copied_parameter_table():
    readme = (ROOT / "scenes" / "README.md").read_text()
    ref = _params()["2"]
    copied = [s["name"] for s in ref["settings"] + ref["instance"] + ref["control"] if re.search(rf"^\| `{s['name']}` \|", readme, re.M)]
    assert not copied, f"scenes/README.md repeats declared parameters: {copied}"
