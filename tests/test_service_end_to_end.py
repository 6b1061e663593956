"""End to end: a session from scenes/drop2d.json, an instance added while it runs, frames over the
WebSocket, a seek back into the replay history, an HDF5 export read back with h5py."""

from __future__ import annotations

import time

import h5py
import numpy as np
import pytest

from flowclip import ApiError, rest_world_matrix
from service_helpers import drop_scene_without_instances, positions_of, quantum

FOLLOW = 20  # frames played after the instance's first frame


def _messages_until(stream, done, timeout=120.0):
    """Messages received until done(messages) holds (those a wait_* skipped included)."""
    seen, deadline = list(stream.skipped), time.monotonic() + timeout
    stream.skipped.clear()
    while not done(seen):
        if time.monotonic() > deadline:
            raise TimeoutError(f"got {[(m['type'], m.get('frame')) for m in seen]}")
        seen.append(stream.recv(timeout=max(0.01, deadline - time.monotonic())))
    return seen


def test_instance_added_while_playing_takes_effect_at_its_frame(server, client, tmp_path):
    scene = client.scene("drop2d")
    assert [i["template"] for i in scene.get("instances", [])] == ["drop2d"], "scenes/drop2d.json changed"
    st = client.create_session(drop_scene_without_instances(client, "drop2d-e2e"), playback_speed=0)
    sid = st["id"]
    assert (st["status"], st["frame"], st["instances"], st["dimension"]) == ("paused", 0, 0, 2)
    liquid = st["particles"]["liquid"]
    assert liquid > 1000

    template = client.template("drop2d")
    centre = (np.asarray(template["region_min"][:2]) + np.asarray(template["region_max"][:2])) / 2
    where = centre + [-0.05, 0.0]  # the drop still falls through air, 5 cm left of where it was recorded

    with server.stream(sid) as stream:
        hello = stream.recv()
        assert hello["type"] == "state" and hello["status"] == "paused" and hello["session_id"] == sid
        f0 = stream.wait("frame")
        assert f0["frame"] == 0 and f0["positions"].shape == (liquid, 2) and f0["session_id"] == sid

        client.step(sid, 3)
        early = [f0] + stream.frames_until(3)
        st = client.wait_paused(sid)
        assert st["frame"] == 3 and st["status"] == "paused"

        # Add the instance while the session plays, starting at 1 s: the answer names the first
        # frame it changes (frame 60 ends at 1 s), and no frame before it is simulated again.
        client.play(sid)
        early += stream.frames_until(6, timeout=300)
        added = client.add_instance(sid, {"name": "drop", "template": "drop2d", "start": 1.0,
                                          "transform": [{"time": 0, "translation": list(where)}]})
        edit = added["edit"]
        assert edit["accepted"] and edit["type"] == "add_instance" and edit["instance"] == "drop"
        first = edit["frame"]
        assert first == 61
        assert added["instance"]["name"] == "drop" and added["instance"]["template"] == "drop2d"
        assert [i["name"] for i in client.instances(sid)] == ["drop"]
        assert client.session(sid)["instances"] == 1

        played = stream.frames_until(first + FOLLOW, timeout=600)
        paused = client.pause(sid)
        assert paused["status"] == "paused"
        newest = client.wait_paused(sid)["frame"]
        assert newest >= first + FOLLOW

        frames = early + played
        numbers = [f["frame"] for f in frames]
        assert numbers == sorted(set(numbers)), "frames are sent in order, never twice"
        before = [f for f in frames if f["frame"] < first]
        after = [f for f in frames if f["frame"] >= first]
        assert before and after
        for f in before:
            assert not any(i["name"] == "drop" and i["active"] for i in f["instances"]), f["frame"]
            assert (f["kind"] == 1).sum() == 0 and f["stats"]["temporary_particles"] == 0, f["frame"]
        expected_matrix = np.eye(3)
        expected_matrix[:2, 2] = where - centre
        for f in after:
            (drop,) = [i for i in f["instances"] if i["name"] == "drop"]
            assert drop["active"] and drop["template"] == "drop2d" and drop["template_frame"] >= 0, f["frame"]
            np.testing.assert_allclose(drop["world_matrix"], expected_matrix, atol=1e-5)
            np.testing.assert_allclose(drop["template_min"], template["region_min"][:2], atol=1e-5)
        # Control acts within the first frames: liquid is steered and temporary particles are seeded
        # where the template has liquid and the scene has none (the falling drop).
        assert max(f["stats"]["controlled_particles"] for f in after) > 0
        assert max(f["stats"]["seeded_particles"] for f in after) > 0 or max((f["kind"] == 1).sum() for f in after) > 0
        assert max((f["kind"] == 1).sum() for f in after) > 0

        # The REST statistics agree: nothing before the instance's frame, control from it on.
        stats = {s["frame"]: s for s in client.stats(sid)}
        assert sorted(stats) == list(range(0, newest + 1))
        assert all(stats[n].get("temporary_particles", 0) == 0 for n in range(first))
        assert all(not any(i.get("active") for i in stats[n].get("instances", [])) for n in range(first))
        assert all(stats[n]["instances"][0]["active"] for n in range(first, newest + 1))
        assert max(stats[n]["controlled_particles"] for n in range(first, newest + 1)) > 0

        # An edit over the WebSocket: acknowledged with the first frame it changes (the
        # instance's start), from which the session re-simulates by itself.
        stream.edit(7, {"type": "update_instance", "name": "drop", "patch": {"attraction_weight": 0.3}})
        ack = stream.wait("ack")
        assert ack == {"type": "ack", "edit_id": 7, "frame": first}
        assert client.instance(sid, "drop")["attraction_weight"] == pytest.approx(0.3)
        # An invalid one is refused and changes nothing.
        stream.edit(8, {"type": "update_instance", "name": "drop", "patch": {"speed": -1}})
        err = stream.wait("error")
        assert err["request_id"] == 8 and err["code"] == "InvalidEdit" and "speed" in err["message"]
        assert client.instance(sid, "drop")["speed"] == 1
        settled = client.wait_paused(sid, timeout=600)  # the re-simulation from `first` done
        assert settled["frame"] == newest and settled["cache"]["valid"] == [[0, newest]]

        # Seek back: the stream shows the recorded frame, equal to the REST frame.
        k = first + 2
        st = client.seek(sid, k)
        assert st["status"] == "paused" and st["shown"] == {"live": False, "frame": k} and st["frame"] == newest
        seen = _messages_until(stream, lambda ms: any(m["type"] == "frame" and m["frame"] == k for m in ms)
                               and any(m["type"] == "state" and m["shown_frame"] == k and not m["live"] for m in ms))
        # The last one: the re-simulation streamed frame k too, before the seek showed it.
        shown = [m for m in seen if m["type"] == "frame" and m["frame"] == k][-1]
        state = next(m for m in seen if m["type"] == "state" and m["shown_frame"] == k and not m["live"])
        assert state["live"] is False and state["frame"] == newest

        rest = client.frame(sid, k)
        assert rest["frame"] == k and rest["count"] == len(shown["positions"])
        assert rest["time"] == pytest.approx(shown["time"])
        tolerance = quantum(rest).max() + 1e-6
        np.testing.assert_allclose(shown["positions"], positions_of(rest), atol=tolerance)
        np.testing.assert_array_equal(shown["kind"], rest["kind"])
        np.testing.assert_array_equal(shown["phase"], rest["phase"])
        (rest_drop,) = rest["instances"]
        np.testing.assert_allclose(rest_world_matrix(rest_drop, 2), shown["instances"][0]["world_matrix"], atol=1e-5)
        assert rest_drop["active"] and rest_drop["template"] == "drop2d"
        binary = client.frame(sid, k, binary=True)
        assert binary["frame"] == k
        np.testing.assert_allclose(binary["positions"], shown["positions"], atol=1e-9)
        assert client.frame(sid, "latest")["frame"] == k

        # Play from the frame shown: the recorded frames first, then the simulation goes on
        # after the newest one.
        client.play(sid)
        resumed = stream.wait_frame(newest + 1, timeout=300)
        assert resumed["frame"] == newest + 1 or resumed["frame"] > newest
        client.pause(sid)
    st = client.wait_paused(sid)

    # Export the history and read it back.
    exported = client.export(sid, "e2e")
    first_frame, last_frame = st["history"]["first"], st["history"]["last"]
    assert exported["frames"] == st["history"]["frames"] == last_frame - first_frame + 1
    assert (exported["h5"], exported["xdmf"]) == ("e2e.h5", "e2e.xdmf")
    path = tmp_path / "e2e.h5"
    path.write_bytes(client.download("e2e.h5"))
    assert exported["bytes"] >= path.stat().st_size > 0
    with h5py.File(path, "r") as h5:
        assert h5.attrs["format"] == "flowclip-frames" and int(h5.attrs["dimension"]) == 2
        index = h5["frames/index"][:]
        assert list(index) == list(range(first_frame, last_frame + 1))
        offset = h5["frames/offset"][:]
        assert int(offset[-1]) == exported["particle_rows"] == len(h5["particles/position"])
        position = h5["particles/position"][:]
        lo, hi = np.asarray(rest["domain_min"][:2]), np.asarray(rest["domain_max"][:2])
        assert np.all(position >= lo - 1e-6) and np.all(position <= hi + 1e-6)
        f = int(np.flatnonzero(index == k)[0])
        a, b = int(offset[f]), int(offset[f + 1])
        assert b - a == rest["count"]
        np.testing.assert_allclose(position[a:b], positions_of(rest), atol=tolerance)
        np.testing.assert_array_equal(h5["particles/kind"][a:b], rest["kind"])
        assert h5["frames/time"][f] == pytest.approx(rest["time"])
    xdmf = client.download("e2e.xdmf")
    assert b"Xdmf" in xdmf and b"e2e.h5" in xdmf

    with pytest.raises(ApiError) as exists:
        client.export(sid, "e2e")
    assert exists.value.status == 409 and exists.value.code == "conflict"
    assert client.export(sid, "e2e", first_frame=first, last_frame=first + 1, force=True)["frames"] == 2
