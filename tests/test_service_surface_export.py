"""Surface exports from the service (POST /api/sessions/{id}/export with
"formats", docs/surfaces.md): the job meshes the history, its progress
reaches the session's stream, its files are served, a cancelled job leaves
nothing, and bad requests are refused naming the key. Every response is
validated against proto/openapi.yaml by the `client` fixture.
"""

from __future__ import annotations

import json

import pytest
from flowclip import ApiError, FlowClipServer
from plyfile import PlyData

from service_helpers import small_scene, wait_until


def _played(client, frames, name="surf"):
    sid = client.create_session(scene=small_scene(name))["id"]
    client.step(sid, frames)
    client.wait_paused(sid, timeout=600)
    return sid


def test_a_surface_export_job_meshes_the_history_and_reports_on_the_stream(server, client, tmp_path):
    sid = _played(client, 6)
    with server.stream(sid) as stream:
        stream.wait("state")
        answer = client.export(sid, "meshed", formats=["ply", "points"], surface={"smoothing": 0},
                               format_settings={})
        assert answer["frames"] == 7  # frames 0..6
        job = answer["surface_job"]
        assert job["state"] in ("queued", "running") and job["formats"] == ["ply", "points"]
        # Progress reaches the stream: the session's state "export" as the job goes.
        seen = []
        while not seen or seen[-1]["state"] != "done":
            m = stream.wait("state", where=lambda m: m["state"] and "export" in m["state"], timeout=600)
            seen.append(m["state"]["export"])
        assert seen[-1]["id"] == job["id"] and seen[-1]["frames_done"] == seen[-1]["frames"] == 7
        done_counts = [e["frames_done"] for e in seen]
        assert done_counts == sorted(done_counts) and len(set(done_counts)) > 2
    final = client.wait_export_job(job["id"])
    assert final["state"] == "done" and final["progress"] == 1
    assert final["directory"] == "meshed/" and final["files"][0] == "meshed.export.json"
    assert client.session(sid)["export"]["state"] == "done"
    manifest = client.download("meshed.export.json", export="meshed")  # JSON: decoded by the client
    assert [f["frame"] for f in manifest["frames"]] == list(range(7))
    assert manifest["surface"]["smoothing"] == 0
    assert set(final["files"]) == {"meshed.export.json"} | {f for fr in manifest["frames"] for f in fr["files"]}
    path = tmp_path / "m.ply"
    path.write_bytes(client.download("meshed.0006.ply", export="meshed"))
    ply = PlyData.read(str(path))
    assert ply["vertex"].count > 0 and ply["face"].count > 0
    with pytest.raises(ApiError) as missing:
        client.download("nothing.ply", export="meshed")
    assert missing.value.status == 404
    with pytest.raises(ApiError) as hidden:
        client.download(".meshed.export.json", export="meshed")
    assert hidden.value.status in (400, 404)


def test_a_cancelled_job_leaves_no_directory(server, client):
    # 201 frames at the finest voxel: far longer than the cancel takes to arrive.
    sid = _played(client, 200, "cancel")
    job = client.export(sid, "cancelled", formats=["vdb", "ply", "obj"], surface={"voxel_size": 0.1})["surface_job"]
    wait_until(lambda: client.export_job(job["id"])["frames_done"] >= 1, timeout=600, what="a frame meshed")
    cancelled = client.cancel_export_job(job["id"])
    assert cancelled["cancel_requested"] or cancelled["state"] == "cancelled"
    end = client.wait_export_job(job["id"])
    assert end["state"] == "cancelled" and end["frames_done"] < end["frames"]
    assert not (server.exports / "cancelled").exists()
    assert not [p.name for p in server.exports.iterdir() if p.name.startswith(".cancelled")]
    assert client.cancel_export_job(job["id"])["state"] == "cancelled"  # again: as it is
    # The particle export itself stays: it was complete before the job began.
    assert (server.exports / "cancelled.h5").exists()


@pytest.mark.parametrize("body, status, path", [
    ({"formats": ["stl"]}, 422, "formats"),
    ({"formats": []}, 422, "formats"),
    ({"formats": "ply"}, 422, "formats"),
    ({"formats": ["ply"], "surface": {"voxel_size": 0}}, 422, "surface.voxel_size"),
    ({"formats": ["ply"], "surface": {"blur": 1}}, 422, "surface.blur"),
    ({"formats": ["ply"], "surface": {"surface_radius": 3, "kernel_radius": 2}}, 422, "surface.surface_radius"),
    ({"formats": ["ply"], "format_settings": {"usd": {"meshes": True}}}, 422, "format_settings.usd"),
    ({"formats": ["usd"], "format_settings": {"usd": {"meshes": 2}}}, 422, "format_settings.usd.meshes"),
    ({"surface": {"smoothing": 1}}, 422, "surface"),
])
def test_bad_surface_requests_name_their_key_and_write_nothing(server, client, body, status, path):
    sid = _played(client, 1, "bad")
    with pytest.raises(ApiError) as e:
        client.op("exportFrames", {"name": "refused", **body}, id=sid)
    assert e.value.status == status and e.value.path == path, e.value
    assert not (server.exports / "refused.h5").exists()
    assert not (server.exports / "refused").exists()


def test_job_ids_are_checked(client):
    for bad, status in (("r1", 400), ("x0", 400), ("x999999", 404)):
        with pytest.raises(ApiError) as e:
            client.export_job(bad)
        assert e.value.status == status


def test_a_history_without_ids_makes_a_usd_stage_without_ids(server, client, tmp_path):
    """A session's history carries no particle ids: the stage says nothing rather than rows for ids."""
    from pxr import Usd, UsdGeom

    sid = _played(client, 3, "usd")
    job = client.wait_export_job(client.export(sid, "staged", formats=["usd"])["surface_job"]["id"])
    assert job["state"] == "done" and job["files"] == ["staged.export.json", "staged.usda"]
    path = tmp_path / "staged.usda"
    path.write_bytes(client.download("staged.usda", export="staged"))
    stage = Usd.Stage.Open(str(path))
    points = UsdGeom.Points(stage.GetPrimAtPath("/flowclip/particles"))
    assert points.GetPointsAttr().GetTimeSamples() == [0, 1, 2, 3]
    assert len(points.GetPointsAttr().Get(3)) == 100
    assert not points.GetIdsAttr().HasAuthoredValue()


def test_a_server_killed_during_an_export_job_leaves_nothing_behind(template_dir, scene_dir, tmp_path):
    """The job writes into a hidden folder that only becomes EXPORTS/NAME/ whole: after a SIGKILL the
    next server removes that folder, and no half export appears under the final name."""
    exports = tmp_path / "exports"
    exports.mkdir()

    def staged():
        return [p for p in exports.iterdir() if p.is_dir() and p.name.startswith(".shot.stage-")]

    with FlowClipServer(template_dir, scene_dir, exports) as s:
        c = s.client()
        sid = c.create_session(scene=small_scene("killed", particles_per_side=20))["id"]
        c.step(sid, 30)
        c.wait_paused(sid, timeout=600)
        # A fine voxel makes every frame's slab slow to mesh: the job is caught with frames written.
        job = c.export(sid, "shot", formats=["vdb", "ply"], surface={"voxel_size": 0.1})["surface_job"]
        wait_until(lambda: staged() and any(staged()[0].iterdir()), timeout=600, what="a frame in the staging folder")
        state = c.export_job(job["id"])
        assert state["state"] == "running" and state["frames_done"] < state["frames"], state
        s.proc.kill()
        s.proc.wait()
    assert len(staged()) == 1 and not (exports / "shot").exists()
    with FlowClipServer(template_dir, scene_dir, exports) as s:
        assert staged() == [] and not (exports / "shot").exists()
        assert (exports / "shot.h5").exists()  # the particle history was complete before the job began
