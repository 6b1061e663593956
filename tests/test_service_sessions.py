"""Sessions side by side: independent simulations, deletion, the session limit."""

from __future__ import annotations

import numpy as np
import pytest
from websockets.exceptions import InvalidStatus

from flowclip import ApiError, FlowClipServer
from service_helpers import positions_of, small_scene


def moving_scene():
    """400 particles thrown to the right at 1 m/s: every frame differs from the last."""
    scene = small_scene("pair", particles_per_side=20, radius=0.01)
    scene["fluid_blocks"][0]["velocity"] = [1.0, 0.0]
    return scene


def test_two_sessions_advance_independently_and_deleting_one_leaves_the_other(server, client):
    a = client.create_session(moving_scene(), threads=1, playback_speed=0)["id"]
    b = client.create_session(moving_scene(), threads=1, playback_speed=0)["id"]
    assert a != b
    assert {s["id"] for s in client.sessions()} == {a, b}
    assert client.health()["sessions"] == 2

    client.step(a, 20)
    client.step(b, 5)
    sa, sb = client.wait_paused(a), client.wait_paused(b)
    assert (sa["frame"], sa["history"]["last"], sa["history"]["frames"]) == (20, 20, 21)
    assert (sb["frame"], sb["history"]["last"], sb["history"]["frames"]) == (5, 5, 6)
    assert sa["time"] == pytest.approx(20 / 60) and sb["time"] == pytest.approx(5 / 60)

    # Same scene, same start: frame 5 is the same in both; B never simulated frame 20.
    a5, b5, a20 = client.frame(a, 5), client.frame(b, 5), client.frame(a, 20)
    np.testing.assert_allclose(positions_of(a5), positions_of(b5), atol=1e-4)
    assert np.abs(positions_of(a20) - positions_of(a5)).max() > 0.05, "the block moved on in A"
    with pytest.raises(ApiError) as missing:
        client.frame(b, 20)
    assert missing.value.status == 404 and missing.value.code == "not_found"
    assert client.frame(b, "latest")["frame"] == 5

    deleted = client.delete_session(a)
    assert deleted == {"deleted": a}
    for call in (lambda: client.session(a), lambda: client.frame(a, 5), lambda: client.step(a, 1)):
        with pytest.raises(ApiError) as gone:
            call()
        assert gone.value.status == 404
    with pytest.raises(InvalidStatus) as refused:
        server.stream(a).close()
    assert refused.value.response.status_code == 404
    assert [s["id"] for s in client.sessions()] == [b] and client.health()["sessions"] == 1

    # B goes on where it was, its recorded frames untouched.
    client.step(b, 3)
    assert client.wait_paused(b)["frame"] == 8
    np.testing.assert_array_equal(positions_of(client.frame(b, 5)), positions_of(b5))

    # A session run alone computes the same frame 5.
    c = client.create_session(moving_scene(), threads=1, playback_speed=0)["id"]
    assert c not in (a, b)
    client.step(c, 5)
    client.wait_paused(c)
    np.testing.assert_allclose(positions_of(client.frame(c, 5)), positions_of(b5), atol=1e-4)


def test_session_limit(template_dir, scene_dir, openapi):
    with FlowClipServer(template_dir, scene_dir, max_sessions=2) as server:
        client = server.client()
        client.observers.append(openapi.observe)
        assert client.health()["max_sessions"] == 2
        ids = [client.create_session(small_scene())["id"] for _ in range(2)]
        with pytest.raises(ApiError) as full:
            client.create_session(small_scene())
        assert full.value.status == 429 and full.value.code == "too_many_sessions" and full.value.message
        client.delete_session(ids[0])
        assert client.create_session(small_scene())["status"] == "paused"
    assert server.returncode == 0
