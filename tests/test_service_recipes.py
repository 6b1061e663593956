"""Recording recipes through REST (/api/recipes): a job records a recipe's template into the database on
the server's recording thread, the template is then listed and usable by a session; a repeated request
gets the running job; cancelling leaves no template and no partial file; sessions run meanwhile; bad
requests are refused with a JSON error."""

from __future__ import annotations

import json

import pytest

from flowclip import ApiError, FlowClipServer
from service_helpers import small_scene

NEEDS_TINY = "needs_tiny"


@pytest.fixture(scope="module")
def recipe_server(recipe_dir, tmp_path_factory):
    """A server with an empty database, the small recipes and one scene whose instance needs tiny_tpl."""
    templates, scenes = tmp_path_factory.mktemp("rec-templates"), tmp_path_factory.mktemp("rec-scenes")
    scene = small_scene(NEEDS_TINY)
    scene["instances"] = [{"name": "tiny", "template": "tiny_tpl", "start": 0}]
    (scenes / f"{NEEDS_TINY}.json").write_text(json.dumps(scene))
    with FlowClipServer(templates, scenes, recipes=recipe_dir) as s:
        s.templates = templates
        yield s
    assert s.returncode == 0, "flowclip serve did not stop cleanly on SIGINT:\n" + "\n".join(s.output[-30:])


@pytest.fixture
def api(recipe_server, openapi):
    c = recipe_server.client()
    c.observers.append(openapi.observe)
    yield c
    for st in c.sessions():
        c.delete_session(st["id"])


def refused(call):
    with pytest.raises(ApiError) as e:
        call()
    return e.value


def database_files(server):
    """Every name in the template directory, hidden (staged) files included."""
    return sorted(p.name for p in server.templates.iterdir())


def test_recipes_are_listed_with_the_templates_they_record(api, recipe_dir):
    listed = {r["name"]: r for r in api.recipes()}
    assert set(listed) == {"tiny", "endless"}
    tiny = listed["tiny"]
    assert tiny["dimension"] == 2 and tiny["frames"] == 4 and tiny["recorded"] is False
    assert tiny["templates"] == [{"name": "tiny_tpl", "recorded": False}]
    assert "job" not in tiny and "last_seconds" not in tiny


def test_a_recorded_recipe_gives_a_template_a_scene_can_use(api, recipe_server):
    (scene,) = api.scenes()
    assert scene["missing_templates"] == ["tiny_tpl"]
    assert refused(lambda: api.create_session(NEEDS_TINY)).status == 422

    job = api.record_recipe("tiny")
    assert job["id"].startswith("r") and job["recipe"] == "tiny" and job["templates"] == ["tiny_tpl"]
    assert job["state"] in ("queued", "running", "done") and job["frames"] == 4
    done = api.wait_recipe_job(job["id"])
    assert done["state"] == "done", done
    assert done["progress"] == 1 and done["frames_done"] == done["frames"] == 4

    assert api.template("tiny_tpl")["frames"] == 5
    assert database_files(recipe_server) == ["tiny_tpl.h5"]
    assert "missing_templates" not in api.scenes()[0]
    listed = {r["name"]: r for r in api.recipes()}
    assert listed["tiny"]["recorded"] is True and listed["tiny"]["last_seconds"] >= 0

    # The scene that needed it opens and runs with its instance steering.
    sid = api.create_session(NEEDS_TINY)["id"]
    api.step(sid, 3)
    st = api.wait_paused(sid)
    assert st["status"] == "paused" and st["frame"] == 3
    (inst,) = api.frame(sid, 3)["instances"]
    assert inst["template"] == "tiny_tpl" and inst["active"]

    conflict = refused(lambda: api.record_recipe("tiny"))
    assert conflict.status == 409 and "force" in conflict.message
    again = api.wait_recipe_job(api.record_recipe("tiny", force=True)["id"])
    assert again["state"] == "done" and database_files(recipe_server) == ["tiny_tpl.h5"]
    assert refused(lambda: api.cancel_recipe_job(again["id"])).status == 409


def test_a_second_request_gets_the_running_job_and_cancelling_writes_nothing(api, recipe_server):
    job = api.record_recipe("endless")
    running = api.wait_recipe_job(job["id"], until=lambda j: j["frames_done"] >= 2, timeout=120)
    assert running["state"] == "running" and 0 < running["progress"] < 1 and running["frames"] == 99999
    assert {r["name"]: r for r in api.recipes()}["endless"]["job"] == job["id"]

    r = api.request("POST", "/api/recipes/{name}/record", name="endless")
    assert r.status_code == 200 and r.json()["id"] == job["id"]

    # Sessions simulate meanwhile: the recording has a thread of its own.
    sid = api.create_session(small_scene("meanwhile"))["id"]
    api.step(sid, 5)
    assert api.wait_paused(sid, timeout=120)["frame"] == 5
    assert api.recipe_job(job["id"])["state"] == "running"

    cancelling = api.cancel_recipe_job(job["id"])
    assert cancelling["cancel_requested"] is True
    cancelled = api.wait_recipe_job(job["id"], timeout=120)
    assert cancelled["state"] == "cancelled" and "error" not in cancelled
    assert api.cancel_recipe_job(job["id"])["state"] == "cancelled"
    assert not any(n.startswith("endless_tpl") or "endless_tpl" in n for n in database_files(recipe_server))
    assert "endless_tpl" not in {t["name"] for t in api.templates()}
    assert "job" not in {r["name"]: r for r in api.recipes()}["endless"]


def test_bad_recipe_requests_get_json_errors(api, recipe_dir):
    e = refused(lambda: api.record_recipe("nosuch"))
    assert e.status == 404 and e.code == "not_found" and "nosuch" in e.message
    e = refused(lambda: api.record_recipe("../tiny"))
    assert e.status == 400 and e.path == "name"
    e = refused(lambda: api.call("POST", "/api/recipes/{name}/record", {"forse": True}, name="tiny"))
    assert e.status == 400 and e.path == "forse"
    for bad in ("x", "r0", "r01", "r1x", "s1"):
        e = refused(lambda: api.recipe_job(bad))
        assert e.status == 400 and e.path == "id", bad
    assert refused(lambda: api.recipe_job("r999")).status == 404
    assert refused(lambda: api.cancel_recipe_job("r999")).status == 404
    r = api.request("POST", "/api/recipes/jobs/{id}", id="r1")
    assert r.status_code == 405 and set(r.headers["Allow"].split(", ")) == {"GET", "DELETE"}

    (recipe_dir / "broken.json").write_text(json.dumps({**small_scene("broken"), "capture": {"name": "b"}}))
    try:
        e = refused(lambda: api.record_recipe("broken"))
        assert e.status == 422 and "broken.json" in e.message and e.path == "capture.region"
        broken = {r["name"]: r for r in api.recipes()}["broken"]
        assert "capture.region" in broken["error"]
    finally:
        (recipe_dir / "broken.json").unlink()
