"""Requests, headers, messages and values that once took the server down or held it, each with the
answer it now gets: a JSON error naming what is wrong, nothing written, and the server still
serving (the module's server must also stop cleanly on SIGINT: conftest checks its exit status)."""

from __future__ import annotations

import json
import socket
import subprocess
import time

import flatbuffers
import pytest
import requests

from flowclip import FlowClipServer, finish_envelope
from flowclip.wire import Edit as fbEdit
from flowclip.wire.Message import Message
from repo_paths import FLOWCLIP_BIN
from service_helpers import small_scene, wait_until


def raw_http(server, request: bytes, timeout=20.0) -> tuple[int, dict]:
    """Sends bytes as they are (requests refuses non-ASCII headers) and parses the answer."""
    host, port = server.url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=timeout) as s:
        s.sendall(request)
        data = b""
        while b"\r\n\r\n" not in data:
            chunk = s.recv(65536)
            if not chunk:
                break
            data += chunk
        head, _, body = data.partition(b"\r\n\r\n")
        length = int([line.split(b":")[1] for line in head.split(b"\r\n") if line.lower().startswith(b"content-length")][0])
        while len(body) < length:
            chunk = s.recv(65536)
            if not chunk:
                break
            body += chunk
    status = int(head.split(b" ")[1])
    return status, json.loads(body.decode("utf-8"))  # strict: the answer must be UTF-8


def endless_scene(name="endless"):
    """1 s frames at 1 µs substeps: a frame that would run for minutes."""
    scene = small_scene(name, particles_per_side=20)
    scene["settings"] = {"frame_rate": 1, "dt_min": 1e-6, "dt_max": 1e-6, "max_substeps_per_frame": 10_000_000}
    return scene


@pytest.mark.parametrize("path", ["/api/scenes/%ff", "/api/templates/%c0%ae", "/api/exports/%ff.h5",
                                  "/api/sessions/%ff", "/api/templates/%ff/preview",
                                  "/api/sessions/%ff/instances/%fe"])
def test_non_utf8_bytes_in_paths_are_echoed_printably(server, client, path):
    r = requests.get(server.url + path, timeout=20)
    assert r.status_code in (400, 404), r.text
    message = r.json()["error"]["message"]
    assert "\\x" in message, message
    assert client.health()["status"] == "ok"


def test_non_utf8_bytes_in_bodies_headers_and_names(server, client):
    host = server.url.removeprefix("http://")
    body = b'{"scene":"dr\xffop"}'
    status, answer = raw_http(server, b"POST /api/sessions HTTP/1.1\r\nHost: " + host.encode() +
                              b"\r\nContent-Type: application/json\r\nContent-Length: " + str(len(body)).encode() +
                              b"\r\nConnection: close\r\n\r\n" + body)
    assert status == 400 and "malformed JSON" in answer["error"]["message"], answer
    status, answer = raw_http(server, b"GET /api/health HTTP/1.1\r\nHost: ev\xffil:1\r\nConnection: close\r\n\r\n")
    assert status == 403 and "\\xFF" in answer["error"]["message"], answer
    status, answer = raw_http(server, b"GET /api/health HTTP/1.1\r\nHost: " + host.encode() +
                              b"\r\nOrigin: http://\xff\xfe\r\nConnection: close\r\n\r\n")
    assert status == 403, answer
    # The WebSocket upgrade checks the same headers before it hands the socket over.
    upgrade = (b"GET /api/sessions/s1/stream HTTP/1.1\r\nHost: \xff\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
               b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n")
    status, answer = raw_http(server, upgrade)
    assert status == 403 and "\\xFF" in answer["error"]["message"], answer
    assert client.sessions() == [] and client.health()["status"] == "ok"


def test_a_server_with_a_token_survives_non_utf8_headers(template_dir, scene_dir):
    with FlowClipServer(template_dir, scene_dir, token="t0k") as server:
        status, answer = raw_http(server, b"GET /api/health HTTP/1.1\r\nHost: \xff\xff\r\nConnection: close\r\n\r\n")
        assert status == 401, answer
        assert server.client().health()["status"] == "ok"
    assert server.returncode == 0


def test_websocket_errors_echo_client_bytes_as_utf8(server, client):
    sid = client.create_session(small_scene(), threads=1)["id"]
    with server.stream(sid) as stream:
        assert stream.wait("frame")["frame"] == 0
        b = flatbuffers.Builder(256)
        text = b.CreateString(b'{"type": "remove_instance", "name": "\xff\xfe"}')
        fbEdit.Start(b)
        fbEdit.AddEditId(b, 7)
        fbEdit.AddJson(b, text)
        stream.send(finish_envelope(b, Message.Edit, fbEdit.End(b)))
        e = stream.wait("error")  # decoding it would raise on invalid UTF-8
        assert e["request_id"] == 7 and e["code"] == "InvalidEdit" and "\\xFF" in e["message"], e
        stream.transport("step", steps=1, request_id=8)
        assert stream.wait_frame(1)["frame"] == 1


def test_number_overflow_in_a_body_is_400_naming_the_key(client):
    r = client.request("POST", "/api/sessions", data='{"scene": "drop2d", "playback_speed": 1e999}',
                       headers={"Content-Type": "application/json"})
    assert r.status_code == 400, r.text
    error = r.json()["error"]
    assert error["path"] == "playback_speed" and "1e999" in error["message"], error
    assert client.sessions() == []


def test_values_outside_their_physical_range_are_refused(client, server, tmp_path):
    for key, value, path in (("gravity", [0, -1e30], "scene.gravity"),
                             ("phases", [{"name": "w", "rest_density": 1e30}], "scene.phases[0].rest_density")):
        scene = small_scene()
        scene[key] = value
        r = client.request("POST", "/api/sessions", json_body={"scene": scene})
        assert r.status_code == 422 and r.json()["error"]["path"] == path, r.text
    assert client.sessions() == []
    # flowclip run: exit status 2, the key named, nothing simulated.
    scene = small_scene()
    scene["gravity"] = [0, -1e30]
    (tmp_path / "g.json").write_text(json.dumps(scene))
    run = subprocess.run([str(FLOWCLIP_BIN), "run", str(tmp_path / "g.json"), "--frames", "1"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "gravity" in run.stderr, run.stderr


def test_client_requests_cannot_raise_the_servers_limits(client):
    for body, key in (({"scene": small_scene(), "history_cap_mb": 1e6}, "history_cap_mb"),
                      ({"scene": small_scene(), "threads": 1024}, "threads")):
        r = client.request("POST", "/api/sessions", json_body=body)
        assert r.status_code == 400 and r.json()["error"]["path"] == key, r.text
    assert client.sessions() == []
    st = client.create_session(small_scene(), history_cap_mb=2, threads=1)
    assert st["history"]["cap"] == 2 * 2**20


def test_merge_patch_content_type_is_accepted_for_patch(client):
    sid = client.create_session(small_scene(), threads=1)["id"]
    client.add_instance(sid, {"name": "drop", "template": "drop2d", "start": 10})
    r = client.request("PATCH", "/api/sessions/{id}/instances/{name}", id=sid, name="drop",
                       data=json.dumps({"speed": 2}), headers={"Content-Type": "application/merge-patch+json"})
    assert r.status_code == 200, r.text
    assert client.instance(sid, "drop")["speed"] == 2
    r = client.request("POST", "/api/sessions/{id}/instances", id=sid, data=json.dumps({"template": "drop2d"}),
                       headers={"Content-Type": "application/merge-patch+json"})
    assert r.status_code == 415, r.text


def test_a_template_in_use_cannot_be_deleted(client, server):
    sid = client.create_session(small_scene(), threads=1)["id"]
    client.add_instance(sid, {"name": "drop", "template": "jet2d", "start": 10})
    r = client.request("DELETE", "/api/templates/{name}", name="jet2d")
    assert r.status_code == 409 and sid in r.json()["error"]["message"], r.text
    assert "jet2d" in [t["name"] for t in client.templates()]


def test_a_runaway_frame_puts_its_session_in_error_and_frees_the_server(template_dir, scene_dir):
    with FlowClipServer(template_dir, scene_dir, extra_args=["--frame-timeout", "0.5"]) as server:
        api = server.client()
        sid = api.create_session(endless_scene(), threads=1)["id"]
        api.step(sid, 1)
        st = wait_until(lambda: (s := api.session(sid))["status"] == "error" and s, timeout=300,
                        what="the watchdog's error state")
        assert "watchdog" in st["error"]["message"] and st["frame"] == 0, st
        api.reset(sid)
        assert api.wait_paused(sid, timeout=300)["status"] == "paused"
        assert api.health()["status"] == "ok"
    assert server.returncode == 0


def test_a_long_frame_holds_neither_workers_nor_delete_nor_sigint(template_dir, scene_dir, openapi):
    with FlowClipServer(template_dir, scene_dir) as server:
        api = server.client()
        api.observers.append(openapi.observe)  # the pending answers too follow proto/openapi.yaml
        sid = api.create_session(endless_scene(), threads=1)["id"]
        api.add_instance(sid, {"name": "drop", "template": "drop2d", "start": 100})
        api.step(sid, 1)
        wait_until(lambda: api.session(sid)["computing"], timeout=300, what="the long frame")
        # Edits wait at most a few seconds for the frame boundary, then answer 202.
        patches = [api.request("PATCH", "/api/sessions/{id}/instances/{name}", id=sid, name="drop",
                               json_body={"speed": 1 + k}) for k in range(3)]
        assert [p.status_code for p in patches] == [202] * 3, [p.text for p in patches]
        # Asked for while they wait, they are pending edits of their kind; an id never handed out is unknown.
        for p in patches:
            e = p.json()["edit"]
            g = api.request("GET", "/api/sessions/{id}/edits/{edit_id}", id=sid, edit_id=e["id"])
            assert g.status_code == 202 and g.json() == {"id": e["id"], "type": "update_instance", "pending": True}, g.text
        unknown = api.request("GET", "/api/sessions/{id}/edits/{edit_id}", id=sid, edit_id=e["id"] + 100)
        assert unknown.status_code == 404, unknown.text
        assert api.health()["status"] == "ok"
        other = api.create_session(small_scene("other"), threads=1)["id"]
        api.step(other, 2)
        assert api.wait_paused(other, timeout=300)["frame"] == 2
        # DELETE answers and the session is gone; its frame stops at the next substep.
        api.delete_session(sid)
        assert sid not in [s["id"] for s in api.sessions()]
        sid2 = api.create_session(endless_scene("again"), threads=1)["id"]
        api.play(sid2)
        wait_until(lambda: api.session(sid2)["computing"], timeout=300, what="the second long frame")
    # SIGINT mid-frame: the server stops (FlowClipServer waits 15 s, then kills: returncode would be -9).
    assert server.returncode == 0, server.output[-20:]


def test_edits_answered_pending_come_back_whole(template_dir, scene_dir, openapi):
    """`--edit-wait 0`: an edit's answer does not wait for its frame boundary, so it is 202 (pending)
    and the client polls it; what the client returns is what the direct answer holds, the added or
    updated instance's object (a slow machine takes this path at the default wait)."""
    with FlowClipServer(template_dir, scene_dir, extra_args=["--edit-wait", "0"]) as server:
        api = server.client()
        api.observers.append(openapi.observe)
        answers = []
        api.observers.append(lambda method, template, r: answers.append((method, template, r.status_code)))
        sid = api.create_session(small_scene("pending"), threads=1)["id"]
        for k in range(3):
            added = api.add_instance(sid, {"name": f"drop{k}", "template": "drop2d", "start": 100})
            assert added["edit"]["accepted"] and added["edit"]["type"] == "add_instance", added
            assert added["instance"]["name"] == f"drop{k}" and added["instance"]["template"] == "drop2d", added
            updated = api.update_instance(sid, f"drop{k}", {"speed": 2 + k})
            assert updated["edit"]["accepted"] and updated["instance"]["speed"] == 2 + k, updated
        pending = [a for a in answers if a[2] == 202 and a[0] in ("POST", "PATCH")]
        assert pending, f"no edit was answered pending with --edit-wait 0: {answers}"
        assert [i["name"] for i in api.instances(sid)] == ["drop0", "drop1", "drop2"]


def test_edit_queue_overflow_is_an_overload_not_an_invalid_edit(server, client):
    sid = client.create_session(endless_scene("queue"), threads=1)["id"]
    client.add_instance(sid, {"name": "drop", "template": "drop2d", "start": 100})
    with server.stream(sid) as stream:
        assert stream.wait("frame")["frame"] == 0
        client.step(sid, 1)
        wait_until(lambda: client.session(sid)["computing"], timeout=300, what="the long frame")
        for k in range(300):
            stream.edit(1000 + k, {"type": "update_instance", "name": "drop", "patch": {"speed": 1 + k % 5}})
        e = stream.wait("error", lambda m: m["code"] == "Overloaded", timeout=60)
        assert e["request_id"] >= 1000 + 256 and "waiting" in e["message"], e
        assert not [m for m in stream.skipped if m["type"] == "error" and m["code"] == "InvalidEdit"]
        r = client.request("PATCH", "/api/sessions/{id}/instances/{name}", id=sid, name="drop",
                           json_body={"speed": 3})
        assert r.status_code == 503 and r.json()["error"]["code"] == "unavailable", r.text
        assert r.headers.get("Retry-After") == "1"
    client.delete_session(sid)


def _open_fds(pid):
    import os
    return len(os.listdir(f"/proc/{pid}/fd"))


def test_websocket_clients_that_never_read_are_dropped(server, client):
    """Raw WebSocket clients that complete the upgrade and never read: once the session is
    deleted (or their socket buffers fill) the server lets go of them within a bounded time."""
    sid = client.create_session(small_scene("flood", particles_per_side=40, radius=0.005), threads=1)["id"]
    host = server.url.removeprefix("http://")
    h, p = host.split(":")
    before = _open_fds(server.proc.pid)
    silent = []
    for k in range(30):
        s = socket.create_connection((h, int(p)), timeout=20)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        s.sendall((f"GET /api/sessions/{sid}/stream HTTP/1.1\r\nHost: {host}\r\nUpgrade: websocket\r\n"
                   "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                   "Sec-WebSocket-Version: 13\r\n\r\n").encode())
        silent.append(s)
    wait_until(lambda: _open_fds(server.proc.pid) >= before + 30, timeout=60, what="30 stream connections")
    client.play(sid)
    wait_until(lambda: client.session(sid)["frame"] >= 30, timeout=600, what="frames streamed at the silent clients")
    client.delete_session(sid)
    # Each connection is closed by the server: the descriptors return to what they were.
    wait_until(lambda: _open_fds(server.proc.pid) <= before + 2, timeout=300, interval=0.5,
               what="the silent connections dropped")
    for s in silent:
        s.close()
    assert client.health()["status"] == "ok"
