"""MkDocs hook: the parameter reference, generated from the declarations.

docs/reference/parameters.md holds a marker; at build time it is replaced by
tables made from `flowclip params` (the same JSON as GET /api/parameters,
built from the ParamTable declarations in server/), so the reference cannot
drift from the code. The binary is $FLOWCLIP_BIN, else build/flowclip.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

from mkdocs.exceptions import PluginError

ROOT = Path(__file__).resolve().parents[2]
MARKER = "<!-- parameter-reference -->"


def _binary() -> Path:
    return Path(os.environ.get("FLOWCLIP_BIN", ROOT / "build" / "flowclip"))


def _load() -> dict:
    binary = _binary()
    if not binary.exists():
        raise PluginError(f"parameter reference: {binary} is missing; build first (make build) or set FLOWCLIP_BIN")
    out = subprocess.run([str(binary), "params"], check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def _num(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int) or (isinstance(v, float) and v.is_integer() and abs(v) < 1e6):
        return str(int(v))
    text = f"{v:g}"
    if "e" in text:
        mantissa, exp = text.split("e")
        text = f"{mantissa}e{int(exp)}"
    return text


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _table(specs2: list[dict], specs3: list[dict]) -> list[str]:
    """One row per parameter; a default that differs by dimension reads '2D / 3D'."""
    by3 = {s["name"]: s for s in specs3}
    names2 = {s["name"] for s in specs2}
    rows = ["| key | type | unit | range | default | meaning |", "|---|---|---|---|---|---|"]
    for s in specs2 + [s for s in specs3 if s["name"] not in names2]:
        t = by3.get(s["name"])
        only = "" if t is not None and s["name"] in names2 else (" (3D only)" if s["name"] not in names2 else " (2D only)")
        span = "" if s["type"] == "boolean" else f"[{_num(s['min'])}, {_num(s['max'])}]"
        default = _num(s["default"])
        if t is not None and t["default"] != s["default"]:
            default = f"{default} / {_num(t['default'])} (2D / 3D)"
        rows.append(f"| `{s['name']}` | {s['type']} | {_cell(s['unit'])} | {span} | {default} | {_cell(s['help'])}{only} |")
    return rows


def _registry(title: str, key: str, ref2: dict, ref3: dict) -> list[str]:
    lines: list[str] = [f"## {title}", ""]
    for name in sorted(set(ref2[key]) | set(ref3[key])):
        e2, e3 = ref2[key].get(name), ref3[key].get(name)
        entry = e2 or e3
        dims = "" if e2 and e3 else (" (2D only)" if e2 else " (3D only)")
        lines += [f"### `{name}`", "", _cell(entry["help"]) + dims, ""]
        params2, params3 = (e2 or e3)["params"], (e3 or e2)["params"]
        lines += (_table(params2, params3) if params2 or params3 else ["No parameters."]) + [""]
    return lines


def render(ref: dict) -> str:
    r2, r3 = ref["2"], ref["3"]
    lines: list[str] = [
        "## Simulation settings: `settings`", "", *_table(r2["settings"], r3["settings"]), "",
        *_registry("Pressure solvers: `solver.method`", "solvers", r2, r3),
        *_registry("Effects: `effects[]`", "effects", r2, r3),
        *_registry("Boundary models: `boundary.method`", "boundaries", r2, r3),
        "## Control settings: `control`", "", *_table(r2["control"], r3["control"]), "",
        "## Instance parameters: `instances[i]`", "",
        "Written flat in the instance object, beside its name, template, transform and time map.", "",
        *_table(r2["instance"], r3["instance"]), "",
        "## Surface settings: `--surface KEY=VALUE`", "",
        "In multiples of the particle radius ([Surfaces and exports](../surfaces.md)).", "",
        *_table(r2["surface"], r3["surface"]), "",
        *_registry("Export formats: `--formats`", "exporters", r2, r3),
        "## Physical ranges", "",
        "Values a scene gives outside the tables above are checked against these ranges.", "",
        "| key | unit | range | meaning |", "|---|---|---|---|",
    ]
    for lim in r2["limits"]:
        lines.append(f"| `{lim['name']}` | {_cell(lim['unit'])} | [{_num(lim['min'])}, {_num(lim['max'])}] | {_cell(lim['help'])} |")
    return "\n".join(lines) + "\n"


def on_page_markdown(markdown: str, page, config, files) -> str:
    if MARKER not in markdown:
        return markdown
    return markdown.replace(MARKER, render(_load()))
