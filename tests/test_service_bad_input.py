"""Bad input: every refusal is a JSON error with its 4xx status, code and a message, the server
goes on serving, and nothing is changed by a refused request."""

from __future__ import annotations

import subprocess

import flatbuffers
import pytest
import requests
from websockets.exceptions import InvalidStatus

from conftest import MAX_BODY_MB
from flowclip import ApiError, FlowClipServer, encode_subscribe, encode_transport
from flowclip.wire import Ack as fbAck
from flowclip.wire import Envelope as fbEnvelope
from flowclip.wire.Message import Message
from repo_paths import FLOWCLIP_BIN
from service_helpers import small_scene


def expect_error(response, status, code):
    assert response.status_code == status, f"{response.status_code} {response.text[:300]}"
    assert response.headers["Content-Type"].startswith("application/json")
    error = response.json()["error"]
    assert error["status"] == status and error["code"] == code, error
    assert error["message"].strip(), error
    return error


@pytest.fixture
def sid(client):
    sid = client.create_session(small_scene("target"), threads=1)["id"]
    client.add_instance(sid, {"name": "drop", "template": "drop2d", "start": 10})
    return sid


def post(client, template, body, **path):
    """A POST with a raw (possibly malformed) body."""
    return client.request("POST", template, data=body, headers={"Content-Type": "application/json"}, **path)


def test_malformed_and_mistyped_bodies_are_400(client, sid):
    expect_error(post(client, "/api/sessions", "{not json"), 400, "bad_request")
    expect_error(post(client, "/api/sessions", '{"scene": "drop2d",}'), 400, "bad_request")
    expect_error(post(client, "/api/sessions", "[1, 2]"), 400, "bad_request")
    expect_error(post(client, "/api/sessions", ""), 400, "bad_request")
    for body in ({"scene": 5}, {"scene": "drop2d", "playback_speed": "fast"}, {"scene": "drop2d", "threads": 1.5},
                 {"scene": "drop2d", "colour": "blue"}, {}):
        expect_error(client.request("POST", "/api/sessions", json_body=body), 400, "bad_request")
    for body in ({"command": "fly"}, {"command": "step", "frames": "3"}, {"command": "seek"},
                 {"command": 3}, {"command": "speed"}, {"command": "play", "speed": 2, "extra": 1}):
        expect_error(client.request("POST", "/api/sessions/{id}/transport", json_body=body, id=sid),
                     400, "bad_request")
    expect_error(post(client, "/api/sessions/{id}/instances", "{", id=sid), 400, "bad_request")
    expect_error(client.request("POST", "/api/sessions/{id}/export", json_body={"name": 3}, id=sid),
                 400, "bad_request")
    expect_error(client.request("GET", "/api/sessions/{id}/edits/{edit_id}", id=sid, edit_id="first"),
                 400, "bad_request")
    assert client.session(sid)["frame"] == 0 and client.health()["status"] == "ok"


def test_unknown_things_are_404(client, sid):
    for method, template, path in (("GET", "/api/sessions/{id}", {"id": "s999"}),
                                   ("DELETE", "/api/sessions/{id}", {"id": "s999"}),
                                   ("GET", "/api/sessions/{id}/frames/{frame}", {"id": "s999", "frame": 0}),
                                   ("GET", "/api/sessions/{id}/frames/{frame}", {"id": sid, "frame": 99}),
                                   ("GET", "/api/sessions/{id}/instances/{name}", {"id": sid, "name": "nope"}),
                                   ("DELETE", "/api/sessions/{id}/instances/{name}", {"id": sid, "name": "nope"}),
                                   ("GET", "/api/sessions/{id}/edits/{edit_id}", {"id": sid, "edit_id": 999}),
                                   ("GET", "/api/templates/{name}", {"name": "nope"}),
                                   ("DELETE", "/api/templates/{name}", {"name": "nope"}),
                                   ("GET", "/api/scenes/{name}", {"name": "nope"}),
                                   ("GET", "/api/exports/{file}", {"file": "nope.h5"})):
        expect_error(client.request(method, template, **path), 404, "not_found")
    expect_error(client.request("PATCH", "/api/sessions/{id}/instances/{name}", json_body={"speed": 2},
                                id=sid, name="nope"), 404, "not_found")
    expect_error(client.request("POST", "/api/sessions/{id}/transport", json_body={"command": "play"}, id="s999"),
                 404, "not_found")
    expect_error(client.request("POST", "/api/sessions", json_body={"scene": "nope"}), 404, "not_found")
    expect_error(client.request("POST", "/api/scenes", json_body={"name": "x", "session": "s999"}), 404, "not_found")
    r = requests.get(client.base_url + "/api/no-such-endpoint", timeout=10)
    assert r.status_code == 404 and r.json()["error"]["code"] == "not_found"
    expect_error(client.request("DELETE", "/api/health"), 405, "method_not_allowed")
    expect_error(client.request("PUT", "/api/sessions/{id}", id=sid), 405, "method_not_allowed")


@pytest.mark.parametrize("raw", ["/api/templates/..%2Fdrop2d", "/api/templates/%2E%2E%2F%2E%2E%2Fetc%2Fpasswd",
                                 "/api/scenes/..%2F..%2Fetc%2Fpasswd", "/api/scenes/%2E%2E",
                                 "/api/exports/..%2Fdrop2d.h5", "/api/exports/%2E%2E%2Fx.xdmf",
                                 "/api/templates/a%00b", "/api/scenes/" + "x" * 65])
def test_path_traversal_in_url_names_is_400(server, client, openapi, raw):
    r = requests.get(server.url + raw, timeout=10)
    template = raw[: raw.rindex("/") + 1] + ("{file}" if "exports" in raw else "{name}")
    openapi.check("GET", template, r.status_code, r.headers.get("Content-Type"), r.json())
    expect_error(r, 400, "bad_request")
    assert client.health()["status"] == "ok"


def test_invalid_names_in_bodies_are_400(client, sid, server):
    client.step(sid, 2)
    client.wait_paused(sid)
    for template, body in (("/api/scenes", {"name": "../x", "session": sid}),
                           ("/api/scenes", {"name": "a/b", "session": sid}),
                           ("/api/sessions/{id}/export", {"name": "../../tmp/x"}),
                           ("/api/sessions/{id}/export", {"name": ""}),
                           ("/api/sessions/{id}/templates", {"name": "..", "region_min": [0, 0],
                                                             "region_max": [1, 1], "first_frame": 0,
                                                             "last_frame": 1})):
        expect_error(client.request("POST", template, json_body=body, id=sid), 400, "bad_request")
    assert not list(server.exports.iterdir()), "nothing was exported"


def test_oversized_bodies_are_413(client, sid):
    big = '{"scene": "drop2d", "name": "' + "x" * int(1.5 * MAX_BODY_MB * 2**20) + '"}'
    expect_error(post(client, "/api/sessions", big), 413, "payload_too_large")
    expect_error(post(client, "/api/sessions/{id}/instances", big, id=sid), 413, "payload_too_large")
    # Just under the limit is read (and refused for what it says).
    small = '{"scene": "nope", "name": "' + "x" * int(0.5 * MAX_BODY_MB * 2**20) + '"}'
    expect_error(post(client, "/api/sessions", small), 404, "not_found")
    assert client.health()["status"] == "ok" and len(client.sessions()) == 1


def test_edits_the_simulation_rejects_are_422_and_change_nothing(client, sid):
    before, scene = client.instances(sid), client.session_scene(sid)
    for instance, key in (({"name": "neg", "template": "drop2d", "speed": -1}, "speed"),
                          ({"name": "ghost", "template": "nope"}, "template"),
                          ({"name": "late", "template": "drop2d", "crop_end": 99}, "crop_end"),
                          ({"name": "drop", "template": "drop2d"}, "name")):
        e = expect_error(client.request("POST", "/api/sessions/{id}/instances", json_body=instance, id=sid),
                         422, "unprocessable")
        assert e["path"].endswith(key), e
    e = expect_error(client.request("PATCH", "/api/sessions/{id}/instances/{name}", json_body={"speed": -1},
                                    id=sid, name="drop"), 422, "unprocessable")
    assert e["path"].endswith("speed"), e
    e = expect_error(client.request("PATCH", "/api/sessions/{id}/settings",
                                    json_body={"settings": {"cfl_factor": 50}}, id=sid), 422, "unprocessable")
    assert e["path"].endswith("cfl_factor"), e
    assert client.instances(sid) == before and client.session_scene(sid) == scene
    # A negative playback speed is refused (400 or 422) and the speed stays.
    speed = client.session(sid)["playback_speed"]
    r = client.request("POST", "/api/sessions/{id}/transport", json_body={"command": "speed", "speed": -1}, id=sid)
    assert r.status_code in (400, 422) and "speed" in r.json()["error"]["message"]
    assert client.session(sid)["playback_speed"] == speed
    expect_error(client.request("POST", "/api/sessions/{id}/transport", json_body={"command": "seek", "frame": 500},
                                id=sid), 422, "unprocessable")
    e = expect_error(client.request("POST", "/api/sessions", json_body={"scene": {**small_scene(), "dimension": 4}}),
                     422, "unprocessable")
    assert e["path"].endswith("dimension"), e


def _ack_from_client():
    b = flatbuffers.Builder(64)
    fbAck.Start(b)
    fbAck.AddEditId(b, 1)
    ack = fbAck.End(b)
    fbEnvelope.Start(b)
    fbEnvelope.AddMessageType(b, Message.Ack)
    fbEnvelope.AddMessage(b, ack)
    b.Finish(fbEnvelope.End(b), file_identifier=b"FCW1")
    return bytes(b.Output())


def test_invalid_websocket_messages_are_answered_and_the_connection_stays_open(server, client, sid):
    with server.stream(sid) as stream:
        assert stream.wait("frame")["frame"] == 0
        valid = encode_subscribe(0, request_id=3)
        garbage = [b"\x00\x01\x02", b"\xff" * 64, valid[:4] + b"XXXX" + valid[8:],
                   valid[:4] + valid[4:8] + b"\xff\xff\xff\x7f" + valid[12:], valid[: len(valid) // 2]]
        for data in garbage:
            stream.send(data)
            e = stream.wait("error")
            assert e["code"] == "InvalidMessage" and e["message"], (data, e)
        stream.send(_ack_from_client())
        assert stream.wait("error")["code"] == "UnsupportedMessage"
        stream.send(encode_transport("seek", request_id=12))  # no frame
        e = stream.wait("error")
        assert e["code"] == "MissingField" and e["request_id"] == 12
        stream.send(encode_transport("step", steps=0, request_id=13))
        e = stream.wait("error")
        assert e["code"] == "InvalidArgument" and e["request_id"] == 13
        stream.edit(14, {"type": "remove_instance"})
        e = stream.wait("error")
        assert e["code"] == "InvalidEdit" and e["request_id"] == 14
        # Still open and working: subscribe, step over the stream, get the frames.
        stream.send(valid)
        stream.transport("step", steps=2, request_id=15)
        assert stream.wait_frame(2)["frame"] == 2
        assert not [m for m in stream.skipped if m["type"] == "error"]
    assert client.health()["status"] == "ok"


def test_requests_without_the_token_are_401(template_dir, scene_dir, openapi):
    token = "s3cret-token"
    with FlowClipServer(template_dir, scene_dir, token=token,
                        extra_args=["--allow-origin", "http://editor.example:5173"]) as server:
        anonymous, wrong, right = server.client(token=""), server.client(token="wrong"), server.client()
        anonymous.http.headers.pop("Authorization", None)
        for c in (anonymous, wrong, right):
            c.observers.append(openapi.observe)
        for c in (anonymous, wrong):
            expect_error(c.request("GET", "/api/health"), 401, "unauthorized")
            expect_error(c.request("POST", "/api/sessions", json_body={"scene": small_scene()}), 401, "unauthorized")
            expect_error(c.request("GET", "/api/templates"), 401, "unauthorized")
        assert right.health()["status"] == "ok" and anonymous.base_url == right.base_url
        sid = right.create_session(small_scene())["id"]
        expect_error(anonymous.request("GET", "/api/sessions/{id}", id=sid), 401, "unauthorized")
        for kw in ({"token": None}, {"token": "wrong"}, {"token": "wrong", "token_as_subprotocol": True}):
            with pytest.raises(InvalidStatus) as refused:
                server.stream(sid, **kw).close()
            assert refused.value.response.status_code == 401
        with server.stream(sid) as stream:  # Authorization header
            assert stream.wait("frame")["frame"] == 0
        with server.stream(sid, token_as_subprotocol=True) as stream:
            assert stream.subprotocol == f"flowclip-token.{token}"
            assert stream.wait("frame")["frame"] == 0
        # Cross-origin upgrades are refused; same-origin ones are fine.
        with pytest.raises(InvalidStatus) as foreign:
            server.stream(sid, origin="http://evil.example").close()
        assert foreign.value.response.status_code == 403
        for origin in (server.url, "http://editor.example:5173"):
            with server.stream(sid, origin=origin) as stream:
                assert stream.wait("frame")["frame"] == 0
        assert right.sessions()[0]["id"] == sid
    assert server.returncode == 0


def test_a_public_host_without_a_token_refuses_to_start(template_dir, scene_dir, tmp_path):
    r = subprocess.run([str(FLOWCLIP_BIN), "serve", "--host", "0.0.0.0", "--port", "0", "--templates",
                        str(template_dir), "--scenes", str(scene_dir), "--exports", str(tmp_path)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "token" in (r.stderr + r.stdout), r


def test_cross_site_requests_are_refused(server, client):
    """A page on another site may send 'simple' requests without asking the server: those are
    refused by Origin, by Content-Type, and (DNS rebinding) by a Host that is not the loopback."""
    url = server.url + "/api/sessions"
    before = len(client.sessions())
    body = '{"scene": "drop2d"}'
    r = requests.post(url, data=body, headers={"Content-Type": "text/plain"}, timeout=10)
    assert expect_error(r, 415, "unsupported_media_type")["message"].startswith("request bodies must be JSON")
    r = requests.post(url, data=body, headers={"Content-Type": "application/json", "Origin": "http://evil.example"},
                      timeout=10)
    expect_error(r, 403, "forbidden")
    r = requests.get(server.url + "/api/health", headers={"Host": "evil.example:8080"}, timeout=10)
    expect_error(r, 403, "forbidden")
    assert len(client.sessions()) == before


def test_the_server_still_serves(client):
    assert client.health()["status"] == "ok"
    sid = client.create_session(small_scene())["id"]
    client.step(sid, 2)
    assert client.wait_paused(sid)["frame"] == 2


def test_instance_names_outside_the_url_alphabet_are_refused(client, sid):
    before = client.instances(sid)
    for name in ("../x", "a b", "x" * 65):
        r = client.request("POST", "/api/sessions/{id}/instances", id=sid,
                           json_body={"name": name, "template": "drop2d", "start": 10})
        assert r.status_code in (400, 422), (name, r.status_code)
    assert client.instances(sid) == before
