"""A small Python client of `flowclip serve` (proto/openapi.yaml, proto/flowclip.fbs).

Headless use, e.g. simulate the drop scene for a second and export it::

    from flowclip_client import FlowClipServer

    with FlowClipServer(templates="templates", scenes="scenes") as server:
        api = server.client()
        sid = api.create_session("drop2d")["id"]
        with server.stream(sid) as stream:
            api.step(sid, 60)
            frame = stream.wait_frame(60)          # decoded: numpy positions, kinds, instances
            print(frame["frame"], frame["positions"].shape, frame["stats"]["temporary_particles"])
        print(api.export(sid, "drop"))             # EXPORTS_DIR/drop.h5 (+ .xdmf)

Three parts:
  FlowClipServer  starts `flowclip serve --port 0 ...` and stops it with SIGINT
  Client          one method per REST operation; errors raise ApiError
  Stream          the WebSocket: decodes Envelope messages into dicts / numpy
                  arrays and sends Subscribe, Transport and Edit messages

Routes are not written here: each method names its operation of
proto/openapi.yaml by operationId (`self.op("getSession", id=sid)`), and
OPERATIONS, read from the spec at import, gives its method and path.
tests/test_service_openapi.py checks that every operation of the spec has a
method here and that every operationId named here is in the spec.

The flatbuffers code is generated at build time (`flatc --python`, see
server/CMakeLists.txt) into BUILD/generated/python, BUILD being the directory
of the flowclip binary (env FLOWCLIP_BIN, default build/flowclip).
"""

from __future__ import annotations

import json
import os
import queue
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from urllib.parse import quote

import flatbuffers
import numpy as np
import requests
import yaml
from websockets.sync.client import connect

ROOT = Path(__file__).resolve().parent.parent
FLOWCLIP_BIN = Path(os.environ.get("FLOWCLIP_BIN", ROOT / "build" / "flowclip"))
OPENAPI_SPEC = ROOT / "proto" / "openapi.yaml"
HTTP_METHODS = ("get", "put", "post", "delete", "patch", "head", "options")


def load_operations(spec_path=OPENAPI_SPEC) -> dict:
    """operationId -> (METHOD, path template) of every operation of the REST contract."""
    spec = yaml.load(Path(spec_path).read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    return {op["operationId"]: (method.upper(), path) for path, item in spec["paths"].items()
            for method, op in item.items() if method in HTTP_METHODS}


OPERATIONS = load_operations()

for _generated in (FLOWCLIP_BIN.parent / "generated" / "python", ROOT / "build" / "generated" / "python"):
    if (_generated / "flowclip" / "wire").is_dir():
        sys.path.insert(0, str(_generated))
        break

from flowclip.wire import Edit as fbEdit  # noqa: E402  (generated code, path set above)
from flowclip.wire import Envelope as fbEnvelope  # noqa: E402
from flowclip.wire import Subscribe as fbSubscribe  # noqa: E402
from flowclip.wire import Transport as fbTransport  # noqa: E402
from flowclip.wire.Ack import Ack  # noqa: E402
from flowclip.wire.Error import Error  # noqa: E402
from flowclip.wire.ErrorCode import ErrorCode  # noqa: E402
from flowclip.wire.Frame import Frame  # noqa: E402
from flowclip.wire.Layer import Layer  # noqa: E402
from flowclip.wire.Message import Message  # noqa: E402
from flowclip.wire.SessionStatus import SessionStatus  # noqa: E402
from flowclip.wire.StateChange import StateChange  # noqa: E402
from flowclip.wire.Stats import Stats  # noqa: E402
from flowclip.wire.TransportCommand import TransportCommand  # noqa: E402

FILE_IDENTIFIER = b"FCW1"
QUANTIZATION_LEVELS = 65535.0


def _enum_names(enum_class):
    return {v: k for k, v in vars(enum_class).items() if not k.startswith("_")}


ERROR_CODES = _enum_names(ErrorCode)                                  # 1 -> "InvalidMessage"
STATUS_NAMES = {v: k.lower() for k, v in vars(SessionStatus).items() if not k.startswith("_")}
TRANSPORT_COMMANDS = {"play": TransportCommand.Play, "pause": TransportCommand.Pause,
                      "step": TransportCommand.Step, "reset": TransportCommand.Reset,
                      "seek": TransportCommand.Seek, "speed": TransportCommand.SetSpeed}
# Stats fields, snake_case -> accessor ("wall_ms" -> Stats.WallMs)
STATS_FIELDS = {re.sub(r"(?<!^)(?=[A-Z])", "_", name).lower(): name
                for name in dir(Stats) if name[0].isupper() and name not in ("Init", "GetRootAs")
                and not name.startswith(("GetRootAs", "StatsBufferHas"))}


# ------------------------------------------------------------------ decoding ---

def _vec3(v, dim):
    return np.array([v.X(), v.Y(), v.Z()])[:dim] if v is not None else np.zeros(dim)


def _points(points, dim):
    """Dequantized positions (count, dim), metres, and the box."""
    if points is None:
        return np.zeros((0, dim)), None, None
    lo, hi = _vec3(points.BoxMin(), dim), _vec3(points.BoxMax(), dim)
    q = points.QAsNumpy()
    q = np.zeros(0, np.uint16) if isinstance(q, int) else q
    q = q.reshape(-1, dim).astype(np.float64)
    return lo + q / QUANTIZATION_LEVELS * (hi - lo), lo, hi


def _array(value, dtype=np.uint8):
    return np.zeros(0, dtype) if isinstance(value, int) else np.asarray(value)


def _decode_frame(f: Frame):
    dim = f.Dimension()
    positions, box_min, box_max = _points(f.Particles(), dim)
    instances = []
    for i in range(f.InstancesLength()):
        inst = f.Instances(i)
        m = _array(inst.WorldMatrixAsNumpy(), np.float32).astype(np.float64)
        instances.append({
            "name": inst.Name().decode(), "template": inst.TemplateName().decode(),
            "active": inst.Active(), "template_frame": inst.TemplateFrame(), "phase": inst.Phase(),
            "world_matrix": m.reshape(dim + 1, dim + 1) if m.size else m,  # row-major (D+1)²
            "template_min": _vec3(inst.TemplateMin(), dim), "template_max": _vec3(inst.TemplateMax(), dim),
            "falloff_width": inst.FalloffWidth(), "fidelity": inst.Fidelity(), "controlled": inst.Controlled(),
            "control_offset": inst.ControlOffset(), "control_count": inst.ControlCount(),
        })
    stats = f.Stats()
    frame = {
        "type": "frame", "session_id": (f.SessionId() or b"").decode(), "frame": f.Frame(), "time": f.Time(),
        "dimension": dim, "domain_min": _vec3(f.DomainMin(), dim), "domain_max": _vec3(f.DomainMax(), dim),
        "layers": f.Layers(), "positions": positions, "box_min": box_min, "box_max": box_max,
        "kind": _array(f.KindAsNumpy()), "phase": _array(f.PhaseAsNumpy()), "instances": instances,
        "stats": {k: getattr(stats, acc)() for k, acc in STATS_FIELDS.items()} if stats else {},
    }
    if f.Layers() & Layer.Control and f.Control() is not None:
        control = f.Control()
        frame["control"], _, _ = _points(control.Points(), dim)
        frame["control_alpha"] = _array(control.AlphaAsNumpy()) / 255.0
    return frame


def decode(buf: bytes) -> dict:
    """One Envelope (file identifier FCW1) as a dict with "type": frame, state, ack or error."""
    buf = bytearray(buf)
    if len(buf) < 8 or not fbEnvelope.Envelope.EnvelopeBufferHasIdentifier(buf, 0):
        raise ValueError("not an FCW1 flatbuffer")
    env = fbEnvelope.Envelope.GetRootAs(buf, 0)
    kind, table = env.MessageType(), env.Message()
    if kind == Message.Frame:
        f = Frame()
        f.Init(table.Bytes, table.Pos)
        return _decode_frame(f)
    if kind == Message.StateChange:
        s = StateChange()
        s.Init(table.Bytes, table.Pos)
        state_json = (s.StateJson() or b"").decode()
        return {"type": "state", "session_id": (s.SessionId() or b"").decode(),
                "status": STATUS_NAMES.get(s.Status(), s.Status()), "frame": s.Frame(), "time": s.Time(),
                "shown_frame": s.ShownFrame(), "live": s.Live(), "playback_speed": s.PlaybackSpeed(),
                "history_first_frame": s.HistoryFirstFrame(), "history_last_frame": s.HistoryLastFrame(),
                "history_dropped_frames": s.HistoryDroppedFrames(), "message": (s.Message() or b"").decode(),
                "request_id": s.RequestId(), "state": json.loads(state_json) if state_json else None}
    if kind == Message.Ack:
        a = Ack()
        a.Init(table.Bytes, table.Pos)
        return {"type": "ack", "edit_id": a.EditId(), "frame": a.Frame()}
    if kind == Message.Error:
        e = Error()
        e.Init(table.Bytes, table.Pos)
        return {"type": "error", "code": ERROR_CODES.get(e.Code(), e.Code()),
                "message": (e.Message() or b"").decode(), "request_id": e.RequestId()}
    raise ValueError(f"unexpected message type {kind} from the server")


# ------------------------------------------------------------------ encoding ---

def _finish(builder, message_type, offset) -> bytes:
    fbEnvelope.Start(builder)
    fbEnvelope.AddMessageType(builder, message_type)
    fbEnvelope.AddMessage(builder, offset)
    builder.Finish(fbEnvelope.End(builder), file_identifier=FILE_IDENTIFIER)
    return bytes(builder.Output())


def encode_subscribe(max_frame_rate=0.0, layers=Layer.Instances, request_id=0) -> bytes:
    b = flatbuffers.Builder(64)
    fbSubscribe.Start(b)
    fbSubscribe.AddRequestId(b, request_id)
    fbSubscribe.AddMaxFrameRate(b, max_frame_rate)
    fbSubscribe.AddLayers(b, layers)
    return _finish(b, Message.Subscribe, fbSubscribe.End(b))


def encode_transport(command, steps=None, frame=None, speed=None, request_id=0) -> bytes:
    """command: play, pause, step (steps), reset, seek (frame), speed (speed)."""
    b = flatbuffers.Builder(64)
    fbTransport.Start(b)
    fbTransport.AddRequestId(b, request_id)
    fbTransport.AddCommand(b, TRANSPORT_COMMANDS[command])
    if steps is not None:
        fbTransport.AddSteps(b, steps)
    if frame is not None:
        fbTransport.AddFrame(b, frame)
    if speed is not None:
        fbTransport.AddSpeed(b, speed)
    return _finish(b, Message.Transport, fbTransport.End(b))


def encode_edit(edit_id, edit: dict) -> bytes:
    """edit: {"type": "add_instance", "instance": {...}} and the other REST edit objects."""
    b = flatbuffers.Builder(256)
    text = b.CreateString(json.dumps(edit))
    fbEdit.Start(b)
    fbEdit.AddEditId(b, edit_id)
    fbEdit.AddJson(b, text)
    return _finish(b, Message.Edit, fbEdit.End(b))


def rest_world_matrix(instance: dict, dim: int) -> np.ndarray:
    """A REST frame instance's world_matrix (4×4 column-major) as the stream's (D+1)² row-major matrix."""
    m = np.asarray(instance["world_matrix"], np.float64).reshape(4, 4).T
    keep = [0, 1, 3] if dim == 2 else [0, 1, 2, 3]
    return m[np.ix_(keep, keep)]


# -------------------------------------------------------------------- REST ---

class ApiError(Exception):
    """An error answer: {"error": {"status", "code", "message", "path"}}."""

    def __init__(self, status, code, message, path=None, body=None):
        super().__init__(f"{status} {code}: {message}" + (f" (at {path})" if path else ""))
        self.status, self.code, self.message, self.path, self.body = status, code, message, path, body


class Client:
    """One method per operation of proto/openapi.yaml. Methods return the decoded JSON body.

    `observers` are called as observer(method, path_template, response) after every
    request (the tests validate each response against the spec that way).
    """

    def __init__(self, base_url, token=None, timeout=30.0):
        self.base_url = base_url.rstrip("/")
        self.http = requests.Session()
        if token is not None:
            self.http.headers["Authorization"] = f"Bearer {token}"
        self.timeout = timeout
        self.observers = []

    def request(self, method, template, *, json_body=None, data=None, params=None, headers=None, **path):
        """A raw request: `template` is the spec's path ("/api/sessions/{id}"), `path` its parameters
        (percent-encoded here, slashes included). Returns the requests.Response, whatever its status."""
        url = self.base_url + template.format(**{k: quote(str(v), safe="") for k, v in path.items()})
        if json_body is not None:
            data, headers = json.dumps(json_body), {"Content-Type": "application/json", **(headers or {})}
        response = self.http.request(method, url, data=data, params=params, headers=headers, timeout=self.timeout)
        for observer in self.observers:
            observer(method, template, response)
        return response

    def call(self, method, template, body=None, **kw):
        """A request whose error answers raise ApiError; returns the JSON body (or bytes)."""
        r = self.request(method, template, json_body=body, **kw)
        if r.status_code >= 400:
            try:
                e = r.json()["error"]
                raise ApiError(r.status_code, e.get("code"), e.get("message"), e.get("path"), r.json())
            except (ValueError, KeyError, TypeError):
                raise ApiError(r.status_code, None, r.text[:200]) from None
        if r.headers.get("Content-Type", "").startswith("application/json"):
            return r.json()
        return r.content

    @staticmethod
    def route(operation_id):
        """(METHOD, path template) of an operation of proto/openapi.yaml."""
        try:
            return OPERATIONS[operation_id]
        except KeyError:
            raise KeyError(f"{operation_id!r} is not an operationId of {OPENAPI_SPEC}") from None

    def op(self, operation_id, body=None, **kw):
        """`call` of the operation named by its operationId; `kw`: path parameters, params, headers."""
        method, template = self.route(operation_id)
        return self.call(method, template, body, **kw)

    # service, templates, scenes
    def health(self):
        return self.op("health")

    def presets(self):
        """The accuracy presets (draft, preview, final) with their measured cost and error."""
        return self.op("presets")

    def parameters(self, dimension=2):
        """Every parameter's declaration (name, unit, min, max, default, type, help)."""
        return self.op("parameters", params={"dimension": dimension})

    def templates(self):
        return self.op("listTemplates")["templates"]

    def template(self, name):
        return self.op("getTemplate", name=name)

    def template_preview(self, name, frame=None, max_points=None):
        """One frame's positions (flattened, every k-th particle, at most max_points) for a thumbnail."""
        query = {k: v for k, v in (("frame", frame), ("max", max_points)) if v is not None}
        return self.op("previewTemplate", name=name, params=query)

    def delete_template(self, name):
        return self.op("deleteTemplate", name=name)

    def record_template(self, sid, name, region_min, region_max, first_frame, last_frame, force=False):
        body = {"name": name, "region_min": list(region_min), "region_max": list(region_max),
                "first_frame": first_frame, "last_frame": last_frame, "force": force}
        return self.op("recordTemplate", body, id=sid)

    # recipes: background recording jobs
    def recipes(self):
        """The recipes the server can record, with their templates and whether each is recorded."""
        return self.op("listRecipes")["recipes"]

    def record_recipe(self, name, force=None):
        """Starts (or returns the running) recording job of recipe `name`."""
        return self.op("recordRecipe", None if force is None else {"force": force}, name=name)

    def recipe_job(self, job_id):
        return self.op("getRecipeJob", id=job_id)

    def cancel_recipe_job(self, job_id):
        return self.op("cancelRecipeJob", id=job_id)

    def wait_recipe_job(self, job_id, until=lambda job: job["state"] in ("done", "failed", "cancelled"),
                        timeout=600.0, poll=0.05):
        """Polls the job until `until(job)` holds (default: it finished); returns the job."""
        deadline = time.monotonic() + timeout
        while True:
            job = self.recipe_job(job_id)
            if until(job):
                return job
            if time.monotonic() > deadline:
                raise TimeoutError(f"recording job {job_id} still {job['state']} "
                                   f"({job['frames_done']}/{job['frames']} frames)")
            time.sleep(poll)

    def scenes(self):
        return self.op("listScenes")["scenes"]

    def scene(self, name):
        return self.op("getScene", name=name)

    def save_scene(self, name, sid, force=False):
        return self.op("saveScene", {"name": name, "session": sid, "force": force})

    # sessions
    def sessions(self):
        return self.op("listSessions")["sessions"]

    def create_session(self, scene, **options):
        """scene: a scene name or an inline scene object; options: name, history_cap_mb,
        playback_speed, threads."""
        return self.op("createSession", {"scene": scene, **options})

    def session(self, sid):
        return self.op("getSession", id=sid)

    def delete_session(self, sid):
        return self.op("deleteSession", id=sid)

    def stats(self, sid):
        return self.op("sessionStats", id=sid)["frames"]

    def session_scene(self, sid):
        return self.op("sessionScene", id=sid)

    def wait_paused(self, sid, timeout=30.0, settle=0.15):
        """Polls the state until the session is paused (or in error) with nothing pending and its
        frame unchanged for `settle` seconds (a pause lets the frame in progress finish)."""
        deadline, last, since = time.monotonic() + timeout, None, 0.0
        while True:
            st = self.session(sid)
            idle = (st["status"] in ("paused", "error") and not st["pending_edits"] and not st["steps_left"]
                    and not (st.get("cache") or {}).get("simulating"))
            if not idle or last is None or st["frame"] != last["frame"]:
                last, since = (st if idle else None), time.monotonic()
            elif time.monotonic() - since >= settle:
                return st
            if time.monotonic() > deadline:
                raise TimeoutError(f"session {sid} still {st['status']} at frame {st['frame']}")
            time.sleep(0.02)

    # edits
    def _edit(self, operation_id, body=None, **path):
        """An edit operation; a pending answer (202) is polled (getEdit) until the edit is applied."""
        result = self.op(operation_id, body, **path)
        deadline = time.monotonic() + 60
        while result["edit"].get("pending"):  # 202: not applied within 3 s
            if time.monotonic() > deadline:
                raise TimeoutError(f"edit {result['edit']['id']} still pending")
            time.sleep(0.1)
            r = self.request(*self.route("getEdit"), id=path["id"], edit_id=result["edit"]["id"])
            if r.status_code == 200:
                result = {**result, "edit": r.json()}
        return result

    def instances(self, sid):
        return self.op("listInstances", id=sid)["instances"]

    def instance(self, sid, name):
        return self.op("getInstance", id=sid, name=name)

    def add_instance(self, sid, instance):
        return self._edit("addInstance", instance, id=sid)

    def update_instance(self, sid, name, patch):
        return self._edit("updateInstance", patch, id=sid, name=name)

    def remove_instance(self, sid, name):
        return self._edit("removeInstance", id=sid, name=name)

    def update_settings(self, sid, settings=None, solver=None, control=None):
        body = {k: v for k, v in (("settings", settings), ("solver", solver), ("control", control)) if v is not None}
        return self._edit("patchSettings", body, id=sid)

    def edit(self, sid, edit_id):
        return self.op("getEdit", id=sid, edit_id=edit_id)

    # transport
    def transport(self, sid, command, **args):
        return self.op("transport", {"command": command, **args}, id=sid)

    def play(self, sid, until=None):
        return self.transport(sid, "play", **({} if until is None else {"until": until}))

    def pause(self, sid):
        return self.transport(sid, "pause")

    def step(self, sid, frames=1):
        return self.transport(sid, "step", frames=frames)

    def seek(self, sid, frame):
        return self.transport(sid, "seek", frame=frame)

    def reset(self, sid):
        return self.transport(sid, "reset")

    def speed(self, sid, speed):
        return self.transport(sid, "speed", speed=speed)

    # frames and exports
    def frame(self, sid, n="latest", binary=False):
        """A recorded frame: the REST JSON, or with binary=True the decoded Envelope{Frame}."""
        if binary:
            return decode(self.op("getFrame", id=sid, frame=n, params={"format": "binary"}))
        return self.op("getFrame", id=sid, frame=n)

    def export(self, sid, name, first_frame=None, last_frame=None, force=False):
        body = {"name": name, "force": force}
        body.update({k: v for k, v in (("first_frame", first_frame), ("last_frame", last_frame)) if v is not None})
        return self.op("exportFrames", body, id=sid)

    def download(self, file):
        """An exported file's bytes (NAME.h5 or NAME.xdmf)."""
        return self.op("getExport", file=file)


# --------------------------------------------------------------- WebSocket ---

class Stream:
    """The session's WebSocket (/api/sessions/{id}/stream). recv() returns decoded messages;
    messages skipped by the wait_* helpers are kept in `skipped`."""

    def __init__(self, base_url, sid, token=None, token_as_subprotocol=False, origin=None, timeout=10.0):
        path = Client.route("stream")[1].format(id=quote(sid, safe=""))
        uri = re.sub(r"^http", "ws", base_url.rstrip("/")) + path
        headers, protocols = {}, None
        if token is not None and token_as_subprotocol:
            protocols = [f"flowclip-token.{token}"]
        elif token is not None:
            headers["Authorization"] = f"Bearer {token}"
        self.ws = connect(uri, additional_headers=headers, subprotocols=protocols, origin=origin,
                          max_size=None, open_timeout=timeout, close_timeout=2)
        self.timeout = timeout
        self.skipped = []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        self.ws.close()

    @property
    def subprotocol(self):
        return self.ws.subprotocol

    def recv(self, timeout=None) -> dict:
        data = self.ws.recv(timeout=self.timeout if timeout is None else timeout)
        if isinstance(data, str):
            raise ValueError(f"text message from the server: {data[:200]!r}")
        return decode(data)

    def wait(self, kind, where=lambda m: True, timeout=None) -> dict:
        """The next message of type `kind` ("frame", "state", "ack", "error") satisfying `where`."""
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"no {kind} message within the timeout")
            m = self.recv(timeout=left)
            if m["type"] == kind and where(m):
                return m
            self.skipped.append(m)

    def wait_frame(self, n, timeout=None) -> dict:
        """The first frame numbered n or later."""
        return self.wait("frame", lambda m: m["frame"] >= n, timeout)

    def frames_until(self, n, timeout=None) -> list:
        """Every frame received until frame n (included); frames may be skipped by the server."""
        frames, deadline = [], time.monotonic() + (self.timeout if timeout is None else timeout)
        while not frames or frames[-1]["frame"] < n:
            frames.append(self.wait("frame", timeout=max(0.01, deadline - time.monotonic())))
        return frames

    def send(self, data: bytes):
        self.ws.send(data)

    def subscribe(self, max_frame_rate=0.0, layers=Layer.Instances, request_id=0):
        self.send(encode_subscribe(max_frame_rate, layers, request_id))

    def transport(self, command, steps=None, frame=None, speed=None, request_id=0):
        self.send(encode_transport(command, steps, frame, speed, request_id))

    def edit(self, edit_id, edit: dict):
        self.send(encode_edit(edit_id, edit))


# ------------------------------------------------------------------ server ---

class FlowClipServer:
    """`flowclip serve` on a free port, stopped with SIGINT on exit (`returncode` then holds its
    exit status). Without `exports` the exports go to a temporary directory."""

    def __init__(self, templates="templates", scenes="scenes", exports=None, *, token=None, max_body_mb=None,
                 history_cap_mb=None, max_sessions=None, recipes=None, extra_args=(), binary=None,
                 startup_timeout=30.0):
        self.binary = Path(binary or FLOWCLIP_BIN)
        self.token = token
        self._tmp = None if exports else tempfile.TemporaryDirectory(prefix="flowclip-exports-")
        self.exports = Path(exports or self._tmp.name)
        self.args = [str(self.binary), "serve", "--host", "127.0.0.1", "--port", "0", "--templates", str(templates),
                     "--scenes", str(scenes), "--exports", str(self.exports)]
        for flag, value in (("--token", token), ("--max-body-mb", max_body_mb),
                            ("--history-cap-mb", history_cap_mb), ("--max-sessions", max_sessions),
                            ("--recipes", recipes)):
            if value is not None:
                self.args += [flag, str(value)]
        self.args += list(extra_args)
        self.startup_timeout = startup_timeout
        self.proc, self.url, self.returncode = None, None, None
        self.output = []  # the server's stdout and stderr lines

    def __enter__(self):
        self.proc = subprocess.Popen(self.args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        lines = queue.Queue()

        def pump():
            for line in self.proc.stdout:
                self.output.append(line.rstrip("\n"))
                lines.put(line)
            lines.put(None)

        threading.Thread(target=pump, daemon=True).start()
        deadline = time.monotonic() + self.startup_timeout
        while self.url is None:
            try:
                line = lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                line = None
            m = re.search(r"listening on (http://\S+)", line or "")
            if m:
                self.url = m.group(1).rstrip("/")
            elif line is None:
                self.stop()
                raise RuntimeError(f"flowclip serve did not start: {' '.join(self.args)}\n" + "\n".join(self.output))
        return self

    def __exit__(self, *exc):
        self.stop()

    def stop(self, timeout=15.0):
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc is not None:
            self.returncode = self.proc.returncode
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
        return self.returncode

    def client(self, token=None):
        return Client(self.url, token=token if token is not None else self.token)

    def stream(self, sid, **kw):
        kw.setdefault("token", self.token)
        return Stream(self.url, sid, **kw)
