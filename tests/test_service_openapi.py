"""proto/openapi.yaml against the server: a scripted tour of every endpoint, each response validated
against the spec's schema for its operation and status; every operation of the spec is exercised.
(Every other service test validates its responses the same way, through the `client` fixture.)

And against its consumers, without a server: the route table of server/service/rest_api.cpp holds
exactly the spec's operations, the Python client has a method for each operation and names no
other, and the shipped scene files are Scenes of the spec. (The editor's consumer check is its type
check: web/src/net is typed from the spec, so `make web` fails on a renamed field or route.)"""

from __future__ import annotations

import ast
import json
import re
from pathlib import Path

import pytest

import flowclip
from flowclip import ApiError, Client, FlowClipServer, Stream, decode, load_operations
from openapi_check import OpenApiChecker
from repo_paths import ROOT
from service_helpers import drop_scene_without_instances

# The repository's spec (the package carries a copy: tests/test_python_package.py).
OPERATIONS = load_operations(ROOT / "proto" / "openapi.yaml")

# Operations served outside rest_api.cpp's table: the WebSocket upgrade (service/http_server.cpp).
NOT_IN_ROUTE_TABLE = {"stream"}


def _shape(path):
    """"/api/sessions/{id}/edits/{edit}" -> "/api/sessions/{}/edits/{}": parameter names may differ."""
    return re.sub(r"\{[^}]*\}", "{}", path)


def test_server_route_table_is_the_spec():
    source = (ROOT / "server" / "service" / "rest_api.cpp").read_text()
    table = re.search(r"ServiceHub::routes\(\) \{(.*?)\n\}", source, re.S)
    assert table, "ServiceHub::routes() not found in server/service/rest_api.cpp"
    routes = re.findall(r'\{\s*"([A-Z]+)",\s*"([^"]+)",\s*&ServiceHub::\w+\s*\}', table.group(1))
    assert len(routes) >= 20, f"the route table's entries did not parse: {routes}"
    served = {(method, _shape(path)) for method, path in routes}
    assert len(served) == len(routes), "a route is in the table twice"
    spec = {(method, _shape(path)) for op, (method, path) in OPERATIONS.items() if op not in NOT_IN_ROUTE_TABLE}
    assert not served - spec, f"routes of rest_api.cpp missing from proto/openapi.yaml: {sorted(served - spec)}"
    assert not spec - served, f"operations of proto/openapi.yaml rest_api.cpp does not route: {sorted(spec - served)}"
    (_, stream) = OPERATIONS["stream"]
    assert stream.endswith("/stream") and '"/stream"' in (ROOT / "server" / "service" / "http_server.cpp").read_text()


def _client_sources():
    """The modules of the installed flowclip package, the generated flowclip.wire aside."""
    return sorted(Path(flowclip.__file__).parent.glob("*.py"))


def _operations_named_by_the_client():
    """operationIds the client's source names: op("X"), _edit("X"), route("X") -> "module.py:line"."""
    named = {}
    for source in _client_sources():
        for node in ast.walk(ast.parse(source.read_text())):
            if not (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)
                    and isinstance(node.args[0].value, str)):
                continue
            func = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", None)
            if func in ("op", "_edit", "route"):
                named.setdefault(node.args[0].value, f"{source.name}:{node.lineno}")
    return named


def test_python_client_has_a_method_per_operation():
    assert {"client.py", "stream.py"} <= {p.name for p in _client_sources()}, _client_sources()
    named = _operations_named_by_the_client()
    unknown = {op: where for op, where in named.items() if op not in OPERATIONS}
    assert not unknown, f"the flowclip package names operationIds proto/openapi.yaml lacks: {unknown}"
    missing = sorted(set(OPERATIONS) - set(named))
    assert not missing, f"operations of proto/openapi.yaml without a method in the flowclip package: {missing}"
    # Routes come from the spec: no path literal in the client's methods.
    for cls in (Client, Stream):
        for name, member in vars(cls).items():
            code = getattr(member, "__code__", None) or getattr(getattr(member, "__func__", None), "__code__", None)
            literals = [c for c in (code.co_consts if code else ()) if isinstance(c, str) and c.startswith("/api/")]
            assert not literals, f"{cls.__name__}.{name} writes a route by hand: {literals}"


def test_operation_ids_are_unique():
    spec = OpenApiChecker().spec
    ids = [op["operationId"] for item in spec["paths"].values() for m, op in item.items() if m != "parameters"]
    assert len(ids) == len(set(ids)) == len(OPERATIONS)


def test_shipped_scenes_are_scenes_of_the_spec(openapi):
    validator = openapi._validator("/components/schemas/Scene")
    scenes = sorted((ROOT / "scenes").rglob("*.json"))
    assert scenes
    for path in scenes:
        validator.validate(json.loads(path.read_text()))


def test_spec_is_a_valid_openapi_document(openapi):
    spec = openapi.spec
    assert spec["openapi"].startswith("3.1")
    from jsonschema import Draft202012Validator

    for name, schema in spec["components"]["schemas"].items():
        Draft202012Validator.check_schema(schema)
    for path, item in spec["paths"].items():
        for method, op in item.items():
            if method == "parameters":
                continue
            assert op["responses"], (method, path)
            names = {p["name"] for p in item.get("parameters", []) + op.get("parameters", [])
                     if "$ref" not in p}
            names |= {spec["components"]["parameters"][p["$ref"].rsplit("/", 1)[1]]["name"]
                      for p in item.get("parameters", []) + op.get("parameters", []) if "$ref" in p}
            assert names >= {s[1:-1] for s in path.split("/") if s.startswith("{")}, (method, path)


def test_tour_of_every_endpoint(server, client, openapi):
    tour = OpenApiChecker()
    client.observers.append(tour.observe)

    def refused(status, call):
        with pytest.raises(ApiError) as e:
            call()
        assert e.value.status == status, e.value
        return e.value

    health = client.health()
    assert health["status"] == "ok" and health["sessions"] == 0
    names = {t["name"] for t in client.templates()}
    assert {"drop2d", "column2d", "jet2d"} <= names
    assert client.template("drop2d")["dimension"] == 2
    params3 = client.parameters(3)
    assert params3["dimension"] == 3 and "dfsph" in params3["solvers"]
    assert any(p["name"] == "falloff_width" for p in params3["instance"])
    presets = client.presets()
    assert isinstance(presets["presets"], list)
    preview = client.template_preview("drop2d", frame=0, max_points=100)
    assert preview["frame"] == 0 and 0 < len(preview["positions"]) <= 200
    scenes = {s["name"]: s for s in client.scenes()}
    assert scenes["drop2d"]["dimension"] == 2 and scenes["drop2d"]["instances"] == 1
    scene = drop_scene_without_instances(client, "tour")

    st = client.create_session(scene, name="tour", playback_speed=0, history_cap_mb=64, threads=0)
    sid = st["id"]
    assert st["name"] == "tour" and st["history"]["cap"] == 64 * 2**20
    assert [s["id"] for s in client.sessions()] == [sid]
    assert client.session(sid)["id"] == sid

    # Edits while paused at frame 0.
    assert client.instances(sid) == []
    added = client.add_instance(sid, {"template": "drop2d", "start": 0})
    name = added["instance"]["name"]
    assert name == "drop2d" and added["edit"]["frame"] == 1
    assert client.instance(sid, name)["template"] == "drop2d"
    patched = client.update_instance(sid, name, {"attraction_weight": 0.25})
    assert patched["instance"]["attraction_weight"] == pytest.approx(0.25) and patched["edit"]["type"] == "update_instance"
    settings = client.update_settings(sid, settings={"cfl_factor": 0.9})
    assert settings["edit"]["type"] == "settings"
    assert client.session_scene(sid)["settings"]["cfl_factor"] == pytest.approx(0.9)
    result = client.edit(sid, added["edit"]["id"])
    assert result["accepted"] and result["frame"] == 1 and result["type"] == "add_instance"

    # Transport.
    assert client.speed(sid, 0)["playback_speed"] == 0
    assert client.step(sid, 3)["status"] in ("stepping", "paused")
    assert client.wait_paused(sid)["frame"] == 3
    client.play(sid)
    client.pause(sid)
    newest = client.wait_paused(sid)["frame"]
    assert newest >= 3
    assert client.seek(sid, 2)["shown"] == {"live": False, "frame": 2}

    # Frames: JSON, binary by query and by Accept header.
    f2 = client.frame(sid, 2)
    assert f2["frame"] == 2 and len(f2["positions"]) == f2["count"] * 2 == len(f2["velocities"])
    assert client.frame(sid, 2, binary=True)["frame"] == 2
    r = client.request("GET", "/api/sessions/{id}/frames/{frame}", id=sid, frame="latest",
                       headers={"Accept": "application/x-flowclip-frame"})
    assert r.status_code == 200 and r.headers["Content-Type"].startswith("application/x-flowclip-frame")
    assert decode(r.content)["frame"] == 2
    stats = client.stats(sid)
    assert [s["frame"] for s in stats] == list(range(newest + 1))

    # Templates recorded from the history.
    region = {"region_min": [0.3, 0.0], "region_max": [0.9, 0.3]}
    recorded = client.record_template(sid, "tour_pool", first_frame=1, last_frame=3, **region)
    assert recorded["name"] == "tour_pool" and recorded["frames"] == 3 and recorded["avg_particles"] > 0
    assert recorded["region_min"][:2] == pytest.approx(region["region_min"])
    assert client.template("tour_pool")["frames"] == 3
    assert refused(409, lambda: client.record_template(sid, "tour_pool", first_frame=1, last_frame=3, **region)).code \
        == "conflict"
    assert client.record_template(sid, "tour_pool", first_frame=1, last_frame=2, force=True, **region)["frames"] == 2
    refused(422, lambda: client.record_template(sid, "tour_far", first_frame=1, last_frame=newest + 50, **region))
    assert client.delete_template("tour_pool") == {"deleted": "tour_pool"}
    refused(404, lambda: client.template("tour_pool"))

    # Scenes saved from the session.
    saved = client.save_scene("tour_saved", sid)
    assert saved["name"] == "tour_saved" and saved["path"].endswith("tour_saved.json")
    again = client.scene("tour_saved")
    assert again["instances"][0]["template"] == "drop2d" and again["settings"]["cfl_factor"] == pytest.approx(0.9)
    assert refused(409, lambda: client.save_scene("tour_saved", sid)).code == "conflict"
    assert client.save_scene("tour_saved", sid, force=True)["name"] == "tour_saved"
    assert client.create_session("tour_saved")["instances"] == 1

    # Recipes recorded in the background.
    recipes = {r["name"]: r for r in client.recipes()}
    assert recipes["tiny"]["templates"] == [{"name": "tiny_tpl", "recorded": False}]
    job = client.record_recipe("tiny")
    assert job["recipe"] == "tiny" and job["state"] in ("queued", "running", "done")
    assert client.wait_recipe_job(job["id"])["state"] == "done"
    assert client.template("tiny_tpl")["frames"] == 5
    assert refused(409, lambda: client.cancel_recipe_job(job["id"])).code == "conflict"
    assert client.delete_template("tiny_tpl") == {"deleted": "tiny_tpl"}

    # Export and download.
    exported = client.export(sid, "tour", first_frame=1, last_frame=3)
    assert exported["frames"] == 3
    assert client.download(exported["h5"])[:8] == b"\x89HDF\r\n\x1a\n"
    assert b"tour.h5" in client.download(exported["xdmf"])
    # With formats: a surface job, its files, and no cancelling a finished one.
    job = client.export(sid, "tour_mesh", first_frame=1, last_frame=2, formats=["ply"])["surface_job"]
    job = client.wait_export_job(job["id"])
    assert job["state"] == "done" and job["files"][0] == "tour_mesh.export.json"
    assert client.download("tour_mesh.0001.ply", export="tour_mesh")[:3] == b"ply"
    assert refused(409, lambda: client.cancel_export_job(job["id"])).code == "conflict"

    # A render job of the session's scene, its result, and no cancelling a finished one.
    assert client.jobs()["available"] is True
    job = client.submit_job(sid, name="tour_job", frames=2, formats=["ply"])
    assert job["state"] == "queued" and len(job["tasks"]) == 1
    job = client.wait_job(job["id"])
    assert job["state"] == "done", job
    task = job["tasks"][0]
    assert "surface/scene.0002.ply" in task["files"]
    assert client.job_file(job["id"], task["id"], "surface/scene.0002.ply")[:3] == b"ply"
    assert client.job_file(job["id"], task["id"], "stats.json")["summary"]["frames"] == 2
    assert [j["id"] for j in client.jobs()["jobs"]] == [job["id"]]
    assert refused(409, lambda: client.cancel_job(job["id"])).code == "conflict"
    assert refused(404, lambda: client.job_file(job["id"], task["id"], "../spec.json")).code == "not_found"

    # The stream (not a REST response: noted by hand).
    with server.stream(sid) as stream:
        assert stream.recv()["type"] == "state"
        assert stream.wait("frame")["frame"] == 2  # the frame shown
    tour.check("GET", "/api/sessions/{id}/stream", 101, None, None)

    assert client.remove_instance(sid, name)["edit"]["type"] == "remove_instance"
    assert client.instances(sid) == []
    # The reset is queued behind the re-simulation the removal started (back
    # to a checkpoint, then up to the newest frame): it answers with any
    # frame on that way, and the session ends paused at frame 0.
    assert 0 <= client.reset(sid)["frame"] <= newest
    assert client.wait_paused(sid)["frame"] == 0
    for s in client.sessions():
        assert client.delete_session(s["id"]) == {"deleted": s["id"]}
    assert client.sessions() == []

    missing = tour.operations() - tour.exercised
    assert not missing, f"operations of proto/openapi.yaml the tour did not exercise: {sorted(missing)}"
    assert tour.checked >= len(tour.operations())


def test_unreadable_templates_and_scenes_are_listed_with_their_error(template_dir, tmp_path, openapi):
    templates, scenes = tmp_path / "templates", tmp_path / "scenes"
    templates.mkdir()
    scenes.mkdir()
    (templates / "drop2d.h5").write_bytes((template_dir / "drop2d.h5").read_bytes())
    (templates / "broken.h5").write_text("not HDF5")
    (scenes / "broken.json").write_text('{"dimension": ')
    with FlowClipServer(templates, scenes) as server:
        client = server.client()
        client.observers.append(openapi.observe)
        listed = {t["name"]: t for t in client.templates()}
        assert set(listed) == {"drop2d", "broken"} and listed["broken"]["error"] and "error" not in listed["drop2d"]
        (scene,) = client.scenes()
        assert scene["name"] == "broken" and scene["dimension"] is None and "broken.json" in scene["error"]
        with pytest.raises(ApiError) as unreadable:
            client.scene("broken")
        assert unreadable.value.status == 422 and "broken.json" in unreadable.value.message
        with pytest.raises(ApiError) as invalid:
            client.create_session("broken")
        assert invalid.value.status == 422
    assert server.returncode == 0
