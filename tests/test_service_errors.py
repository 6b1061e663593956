"""A session whose simulation runs away (non-finite values, or a frame the watchdog stops) stops in
the error state; the server and the other sessions go on."""

from __future__ import annotations

import pytest

from flowclip import ApiError
from service_helpers import blowup_scene, small_scene, wait_until


def test_a_runaway_frame_puts_only_its_session_in_the_error_state(server, client):
    good = client.create_session(small_scene("good"), threads=1, playback_speed=60)["id"]
    bad = client.create_session(blowup_scene(), threads=1, playback_speed=0)["id"]
    client.play(good)
    with server.stream(bad) as stream:
        assert stream.wait("frame")["frame"] == 0
        client.play(bad)
        st = wait_until(lambda: (s := client.session(bad))["status"] == "error" and s, timeout=300,
                        what="the error state")
        error_frame = st["error"]["frame"]
        assert error_frame >= 1 and "more than 20 substeps" in st["error"]["message"]
        # The broken frame was neither recorded nor published.
        assert st["frame"] == error_frame - 1 == st["history"]["last"]
        change = stream.wait("state", lambda m: m["status"] == "error")
        assert "substeps" in change["message"] and change["frame"] == error_frame - 1
        assert all(m["frame"] < error_frame for m in stream.skipped if m["type"] == "frame")
        # Transport over the stream is refused too, and the connection stays usable.
        stream.transport("play", request_id=41)
        refused = stream.wait("error")
        assert refused["request_id"] == 41 and refused["code"] == "Conflict"

    for command in ("play", "step"):
        with pytest.raises(ApiError) as conflict:
            client.transport(bad, command)
        assert conflict.value.status == 409 and conflict.value.code == "conflict" and conflict.value.message
    with pytest.raises(ApiError) as missing:
        client.frame(bad, error_frame)
    assert missing.value.status == 404
    assert client.session(bad)["status"] == "error"

    # The server and the other session carry on.
    health = client.health()
    assert health["status"] == "ok" and health["sessions"] == 2
    g = client.session(good)
    assert g["status"] == "playing" and "error" not in g
    wait_until(lambda: client.session(good)["frame"] >= g["frame"] + 5, timeout=300, what="the good session advancing")
    other = client.create_session(small_scene("other"), threads=1)["id"]
    client.step(other, 2)
    assert client.wait_paused(other)["frame"] == 2
    client.pause(good)

    # Reset clears the error: frame 0, paused, the history restarted.
    client.reset(bad)
    st = client.wait_paused(bad)
    assert st["status"] == "paused" and "error" not in st and st["frame"] == 0
    assert st["history"]["first"] == st["history"]["last"] == 0
