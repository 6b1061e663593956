"""MkDocs hook: the REST reference, generated from proto/openapi.yaml.

docs/reference/rest.md holds a marker; at build time it is replaced by one
section per operation (method, path, summary, parameters, body, answers) and
one per schema, read from the spec the server, the editor's types and the
Python client are checked against, so the page cannot drift from them.
"""

from __future__ import annotations

from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
SPEC = ROOT / "proto" / "openapi.yaml"
MARKER = "<!-- rest-reference -->"
METHODS = ("get", "put", "post", "patch", "delete")


def _cell(text) -> str:
    return str(text or "").replace("|", "\\|").replace("\n", " ").strip()


def _anchor(name: str) -> str:
    return "schema-" + name.lower()


def _type(schema: dict, spec: dict) -> str:
    """A schema in one short phrase: a link to a named schema, or its type with bounds."""
    if not schema:
        return "any"
    if "$ref" in schema:
        name = schema["$ref"].rsplit("/", 1)[-1]
        return f"[{name}](#{_anchor(name)})"
    for key in ("oneOf", "anyOf"):
        if key in schema:
            return " or ".join(_type(s, spec) for s in schema[key])
    t = schema.get("type", "object")
    if isinstance(t, list):
        t = " or ".join(t)
    if t == "array":
        return f"array of {_type(schema.get('items', {}), spec)}"
    bounds = []
    for key, sign in (("minimum", "≥"), ("exclusiveMinimum", ">"), ("maximum", "≤"), ("exclusiveMaximum", "<")):
        if key in schema:
            bounds.append(f"{sign} {schema[key]}")
    if "enum" in schema:
        bounds.append("one of " + ", ".join(f"`{v}`" for v in schema["enum"]))
    if "pattern" in schema:
        bounds.append(f"`{schema['pattern']}`")
    return t + (f" ({', '.join(bounds)})" if bounds else "")


def _resolve(obj: dict, spec: dict) -> dict:
    while isinstance(obj, dict) and "$ref" in obj and obj["$ref"].startswith("#/components/") and len(obj) == 1:
        section, name = obj["$ref"].split("/")[2:4]
        obj = spec["components"][section][name]
    return obj


def _json_schema(content: dict | None) -> dict | None:
    if not content:
        return None
    for media in ("application/json", "application/octet-stream"):
        if media in content:
            return content[media].get("schema", {})
    return next(iter(content.values())).get("schema", {})


def _operation(path: str, method: str, op: dict, shared: list, spec: dict) -> list[str]:
    lines = [f"### `{method.upper()} {path}`", "", f"`{op.get('operationId', '')}`: {_cell(op.get('summary'))}", ""]
    params = [_resolve(p, spec) for p in shared + op.get("parameters", [])]
    if params:
        lines += ["| parameter | in | type | required | meaning |", "|---|---|---|---|---|"]
        for p in params:
            lines.append(f"| `{p['name']}` | {p['in']} | {_type(p.get('schema', {}), spec)} | "
                         f"{'yes' if p.get('required') else 'no'} | {_cell(p.get('description'))} |")
        lines.append("")
    body = _resolve(op.get("requestBody", {}), spec)
    if body:
        lines += [f"Body: {_type(_json_schema(body.get('content')) or {}, spec)}"
                  + ("" if body.get("required") else " (optional)"), ""]
    lines += ["| answer | meaning | body |", "|---|---|---|"]
    for status, response in sorted(op.get("responses", {}).items()):
        r = _resolve(response, spec)
        schema = _json_schema(r.get("content"))
        lines.append(f"| {status} | {_cell(r.get('description'))} | {_type(schema, spec) if schema is not None else ''} |")
    return lines + [""]


def _schema(name: str, schema: dict, spec: dict) -> list[str]:
    lines = [f"### {name} {{#{_anchor(name)}}}", ""]
    if schema.get("description"):
        lines += [_cell(schema["description"]), ""]
    props = schema.get("properties")
    if not props:
        return lines + [f"{_type(schema, spec)}", ""]
    required = set(schema.get("required", []))
    lines += ["| field | type | required | meaning |", "|---|---|---|---|"]
    for field, s in props.items():
        meaning = _cell(s.get("description"))
        if "default" in s:
            meaning += f" (default `{s['default']}`)"
        lines.append(f"| `{field}` | {_type(s, spec)} | {'yes' if field in required else 'no'} | {meaning.strip()} |")
    return lines + [""]


def render(spec: dict) -> str:
    tags = [t["name"] for t in spec.get("tags", [])]
    by_tag: dict[str, list[str]] = {t: [] for t in tags}
    for path, item in spec["paths"].items():
        shared = item.get("parameters", [])
        for method in METHODS:
            if method in item:
                tag = (item[method].get("tags") or ["other"])[0]
                by_tag.setdefault(tag, []).extend(_operation(path, method, item[method], shared, spec))
    lines: list[str] = []
    for tag, ops in by_tag.items():
        if ops:
            lines += [f"## {tag.capitalize()}", "", *ops]
    lines += ["## Schemas", ""]
    for name, schema in spec["components"]["schemas"].items():
        lines += _schema(name, schema, spec)
    return "\n".join(lines) + "\n"


def on_page_markdown(markdown: str, page, config, files) -> str:
    if MARKER not in markdown:
        return markdown
    return markdown.replace(MARKER, render(yaml.safe_load(SPEC.read_text())))
