"""The docs' REST reference is generated from proto/openapi.yaml: every operation has its
section with its answers, and every schema it links to has one."""

from __future__ import annotations

import importlib.util
import re

import yaml

from repo_paths import ROOT

SPEC = yaml.safe_load((ROOT / "proto" / "openapi.yaml").read_text())


def _render() -> str:
    spec = importlib.util.spec_from_file_location("rest_reference", ROOT / "docs" / "hooks" / "rest_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.render(SPEC)


def test_every_operation_has_its_section_and_answers():
    page = _render()
    count = 0
    for path, item in SPEC["paths"].items():
        for method in ("get", "put", "post", "patch", "delete"):
            if method not in item:
                continue
            count += 1
            heading = f"### `{method.upper()} {path}`"
            assert heading in page, heading
            section = page.split(heading, 1)[1].split("\n### ", 1)[0]
            assert f"`{item[method]['operationId']}`" in section
            for status in item[method]["responses"]:
                assert re.search(rf"^\| {status} \|", section, re.M), f"{method} {path}: answer {status}"
    assert count >= 25


def test_every_schema_link_lands_on_a_schema_section():
    page = _render()
    anchors = set(re.findall(r"\{#(schema-[a-z0-9]+)\}", page))
    assert {f"schema-{name.lower()}" for name in SPEC["components"]["schemas"]} == anchors
    links = set(re.findall(r"\]\(#(schema-[a-z0-9]+)\)", page))
    assert links and links <= anchors, links - anchors


def test_a_schema_lists_its_fields_with_defaults_and_required():
    section = _render().split("{#schema-createsessionrequest}", 1)[1].split("\n### ", 1)[0]
    assert re.search(r"^\| `scene` \| \[Name\]\(#schema-name\) or \[Scene\]\(#schema-scene\) \| yes \|", section, re.M)
    assert re.search(r"^\| `checkpoint_every` \| integer \(≥ 0, ≤ 100000\) \| no \| .*\(default `10`\) \|$", section, re.M)
