"""The REST client: one method per operation of the packaged openapi.yaml.

Routes are not written here: each method names its operation by operationId
(`self.op("getSession", id=sid)`) and flowclip.operations gives its method and
path. The repository's tests/test_service_openapi.py checks that every operation
of the spec has a method here and that every operationId named here is in it.
"""

from __future__ import annotations

import json
import time
from urllib.parse import quote

import requests

from .codec import decode
from .operations import route


def _wait_job(fetch, what, job_id, until, timeout, poll):
    """Polls fetch(job_id) until `until(job)` holds; the timeout only catches a hang."""
    deadline = time.monotonic() + timeout
    while True:
        job = fetch(job_id)
        if until(job):
            return job
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what} {job_id} still {job['state']} ({job['frames_done']}/{job['frames']} frames)")
        time.sleep(poll)


class ApiError(Exception):
    """An error answer: {"error": {"status", "code", "message", "path"}}."""

    def __init__(self, status, code, message, path=None, body=None):
        super().__init__(f"{status} {code}: {message}" + (f" (at {path})" if path else ""))
        self.status, self.code, self.message, self.path, self.body = status, code, message, path, body


class Client:
    """One method per operation of the spec (openapi.yaml). Methods return the decoded JSON body.

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
        """(METHOD, path template) of an operation of the spec."""
        return route(operation_id)

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
        return _wait_job(self.recipe_job, "recording job", job_id, until, timeout, poll)

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

    def wait_paused(self, sid, timeout=120.0, settle=0.15):
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
        """An edit operation; a pending answer (202) is polled (getEdit) until the edit is applied, and
        then completed as the direct answer is: an added or updated instance comes with its object."""
        result = self.op(operation_id, body, **path)
        deadline = time.monotonic() + 60
        polled = False
        while result["edit"].get("pending"):  # 202: not applied within the server's --edit-wait
            if time.monotonic() > deadline:
                raise TimeoutError(f"edit {result['edit']['id']} still pending")
            time.sleep(0.1)
            polled = True
            r = self.request(*self.route("getEdit"), id=path["id"], edit_id=result["edit"]["id"])
            if r.status_code == 200:
                result = {**result, "edit": r.json()}
        edit = result["edit"]
        if polled and edit.get("accepted") and edit.get("type") in ("add_instance", "update_instance"):
            r = self.request(*self.route("getInstance"), id=path["id"], name=edit["instance"])
            if r.status_code == 200:  # not if a later edit already renamed or removed it
                result["instance"] = r.json()
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

    def export(self, sid, name, first_frame=None, last_frame=None, force=False, formats=None, surface=None,
               format_settings=None):
        """Exports the session's history as NAME.h5 + NAME.xdmf; with `formats` (e.g. ["vdb", "ply"]) also
        starts a job meshing it into NAME/ (the answer's `surface_job`; wait_export_job follows it)."""
        body = {"name": name, "force": force}
        body.update({k: v for k, v in (("first_frame", first_frame), ("last_frame", last_frame), ("formats", formats),
                                       ("surface", surface), ("format_settings", format_settings)) if v is not None})
        return self.op("exportFrames", body, id=sid)

    def download(self, file, export=None):
        """An exported file's bytes: NAME.h5 or NAME.xdmf, or with `export` a file of that surface export."""
        if export is not None:
            return self.op("getSurfaceFile", name=export, file=file)
        return self.op("getExport", file=file)

    def export_job(self, job_id):
        return self.op("getSurfaceJob", id=job_id)

    def cancel_export_job(self, job_id):
        return self.op("cancelSurfaceJob", id=job_id)

    def wait_export_job(self, job_id, until=lambda job: job["state"] in ("done", "failed", "cancelled"),
                        timeout=600.0, poll=0.05):
        """Polls the surface export job until `until(job)` holds (default: it finished); returns the job."""
        return _wait_job(self.export_job, "export job", job_id, until, timeout, poll)

    def submit_job(self, sid, *, name=None, particle_radius=None, frames=None, seconds=None, formats=None,
                   frames_export=None, overrides=None, wedge=None, threads=None):
        """Runs the session's current scene again as a render job on the server's Dask cluster: at
        `particle_radius`, with `overrides` ({key path: value}) and a `wedge` ({"key": path, "values": [...]},
        one task per value); returns the job (wait_job follows it)."""
        body = {"session": sid}
        body.update({k: v for k, v in (("name", name), ("particle_radius", particle_radius), ("frames", frames),
                                       ("seconds", seconds), ("formats", formats), ("frames_export", frames_export),
                                       ("overrides", overrides), ("wedge", wedge), ("threads", threads))
                     if v is not None})
        return self.op("submitJob", body)

    def jobs(self):
        """{"jobs": [...], "available", "where"}: the server's render jobs and where they run."""
        return self.op("listJobs")

    def job(self, job_id):
        return self.op("getJob", id=job_id)

    def cancel_job(self, job_id):
        return self.op("cancelJob", id=job_id)

    def wait_job(self, job_id, until=lambda job: job["state"] in ("done", "failed", "cancelled"), timeout=1200.0,
                 poll=0.1):
        """Polls the render job until `until(job)` holds (default: it finished); returns the job."""
        return _wait_job(self.job, "render job", job_id, until, timeout, poll)

    def job_file(self, job_id, task, file):
        """A file of a done render job's task (`file` as the job lists it, e.g. "surface/scene.0003.ply")."""
        return self.op("getJobFile", id=job_id, task=task, file=file)
