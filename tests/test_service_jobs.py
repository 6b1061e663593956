"""Render jobs from the service (POST /api/jobs, docs/batch.md): a session's
current scene runs again as a batch on a Dask LocalCluster through
flowclip-batch. A wedge's tasks equal plain `flowclip run`s of their scenes
bit for bit, the job's progress reaches the session's stream, cancel kills
every process of the job and leaves nothing, and bad requests are refused
naming the key before anything is submitted. Every response is validated
against proto/openapi.yaml by the `client` fixture.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest
from flowclip import ApiError, FlowClipServer

from conftest import job_args
from repo_paths import FLOWCLIP_BIN
from service_helpers import wait_until


@pytest.fixture(scope="module")
def server(template_dir, scene_dir, tmp_path_factory):
    with FlowClipServer(template_dir, scene_dir, tmp_path_factory.mktemp("exports"),
                        extra_args=job_args(workers=2)) as s:
        yield s
    assert s.returncode == 0, "flowclip serve did not stop cleanly on SIGINT:\n" + "\n".join(s.output[-30:])


def _drop(client):
    return client.create_session(scene="drop2d")["id"]


def _processes_in(folder: Path) -> list[str]:
    """Processes whose working directory is inside `folder` (a job's runs work in its task folders)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cwd = os.readlink(entry / "cwd")
        except OSError:
            continue
        if cwd.startswith(str(folder)):
            found.append(f"{entry.name} {cwd}")
    return found


def test_a_wedge_job_runs_each_task_as_a_plain_run_and_reports_on_the_stream(server, client, template_dir, tmp_path):
    sid = _drop(client)
    starts = [0.0, 0.1]
    with server.stream(sid) as stream:
        stream.wait("state")
        job = client.submit_job(sid, name="wedge", frames=10, formats=["ply"],
                                wedge={"key": "instances[drop].start", "values": starts})
        assert job["state"] == "queued" and job["name"] == "wedge"
        assert [t["overrides"] for t in job["tasks"]] == [{"instances[drop].start": v} for v in starts]
        # The session's state "jobs" follows the job to its end.
        seen = []
        while not seen or seen[-1]["state"] not in ("done", "failed", "cancelled"):
            m = stream.wait("state", where=lambda m: m["state"] and m["state"].get("jobs"), timeout=600)
            seen.append(m["state"]["jobs"][-1])
    assert seen[-1]["state"] == "done", seen[-1]
    done = [s["frames_done"] for s in seen]
    assert done == sorted(done), done  # never backwards (the stream may merge reports)
    job = client.wait_job(job["id"])
    assert job["progress"] == 1 and job["tasks_done"] == 2 and job["frames_done"] == job["frames"] == 20
    assert job["directory"] == job["id"] + "/"
    folder = server.exports / "jobs" / job["id"]
    assert (folder / "batch.json").exists()
    assert not [p.name for p in (server.exports / "jobs").iterdir() if p.name.startswith(".") and p.name != ".lock"]
    for task, start in zip(job["tasks"], starts):
        assert task["state"] == "done" and task["frame"] == task["frames"] == 10
        assert {"frames.h5", "stats.json", "scene.json", "task.json", "surface/scene.0010.ply"} <= set(task["files"])
        scene = client.job_file(job["id"], task["id"], "scene.json")
        assert scene["instances"][0]["start"] == start
        # The same scene run by hand: the same frames, bit for bit.
        (tmp_path / "scene.json").write_bytes((folder / task["id"] / "scene.json").read_bytes())
        plain = tmp_path / f"plain-{start}.h5"
        subprocess.run([str(FLOWCLIP_BIN), "run", str(tmp_path / "scene.json"), "--frames", "10", "--threads", "1",
                        "--quiet", "--templates", str(template_dir), "--export", str(plain)], check=True, timeout=600)
        with h5py.File(folder / task["id"] / "frames.h5") as a, h5py.File(plain) as b:
            for key in ("frames/index", "particles/position", "particles/velocity"):
                assert np.array_equal(a[key][()], b[key][()]), key
    # The instance starting within the run steers the liquid: the two tasks differ.
    with h5py.File(folder / job["tasks"][0]["id"] / "frames.h5") as a, \
            h5py.File(folder / job["tasks"][1]["id"] / "frames.h5") as b:
        assert not np.array_equal(a["particles/position"][()], b["particles/position"][()])
    assert client.session(sid)["jobs"][-1]["state"] == "done"


def test_cancel_kills_the_job_and_leaves_nothing(server, client):
    sid = _drop(client)
    job = client.submit_job(sid, name="long", frames=100000, frames_export=False,
                            wedge={"key": "instances[drop].speed", "values": [1.0, 1.5]})
    client.wait_job(job["id"], until=lambda j: any(t["frame"] >= 1 for t in j["tasks"]) or j["state"] != "running"
                    and j["state"] != "queued", timeout=600)
    cancelled = client.cancel_job(job["id"])
    assert cancelled["cancel_requested"] or cancelled["state"] == "cancelled"
    end = client.wait_job(job["id"])
    assert end["state"] == "cancelled" and end["frames_done"] < end["frames"]
    jobs = server.exports / "jobs"
    assert not (jobs / job["id"]).exists()
    assert not [p.name for p in jobs.iterdir() if p.name.startswith(f".{job['id']}.")]
    # Every process of the job (the batch, its workers, their flowclip runs) is gone.
    wait_until(lambda: not _processes_in(jobs), timeout=120, what="the job's processes ended")
    assert client.cancel_job(job["id"])["state"] == "cancelled"  # again: as it is
    assert client.session(sid)["jobs"][-1]["state"] == "cancelled"
    # The session's state keeps its newest jobs, oldest first.
    again = client.submit_job(sid, name="after", frames=1, frames_export=False)
    after = client.wait_job(again["id"])
    assert after["state"] == "done", after
    wait_until(lambda: [(j["id"], j["state"]) for j in client.session(sid)["jobs"]]
               == [(job["id"], "cancelled"), (again["id"], "done")], timeout=60, what="both jobs in the state")


@pytest.mark.parametrize("body, status, path", [
    ({"wedge": {"key": "instances[nope].speed", "values": [1]}}, 422, "wedge.key"),
    ({"wedge": {"key": "instances[drop].speed", "values": [1, -3]}}, 422, "wedge.values[1]"),
    ({"wedge": {"key": "instances[drop].speed", "values": []}}, 422, "wedge.values"),
    ({"wedge": {"key": "instances[drop].speed", "values": [1, 1.0]}}, 422, "wedge.values[1]"),
    ({"wedge": {"key": "instances[drop].speed", "values": [1], "step": 2}}, 422, "wedge.step"),
    ({"overrides": {"instances[drop].template": "no_such_template"}}, 422, "overrides"),
    ({"overrides": {"settings.frame_rate": 1e9}}, 422, "overrides"),
    ({"particle_radius": -0.01}, 422, "particle_radius"),
    ({"formats": ["stl"]}, 422, "formats"),
    ({"frames": 5, "seconds": 1}, 400, "seconds"),
    ({"frames": 0}, 400, "frames"),
    ({"threads": "two"}, 400, "threads"),
    ({"colour": "blue"}, 400, "colour"),
])
def test_bad_requests_are_refused_naming_the_key_and_nothing_is_submitted(server, client, body, status, path):
    sid = _drop(client)
    before = len(client.jobs()["jobs"])
    with pytest.raises(ApiError) as e:
        client.submit_job(sid, **body) if "colour" not in body else \
            client.op("submitJob", {"session": sid, **body})
    assert e.value.status == status, e.value
    assert e.value.path and e.value.path.startswith(path), e.value
    assert len(client.jobs()["jobs"]) == before


def test_an_unknown_session_is_404(server, client):
    with pytest.raises(ApiError) as e:
        client.submit_job("s999", frames=1)
    assert e.value.status == 404


def test_without_flowclip_batch_jobs_are_off(template_dir, scene_dir, tmp_path, openapi):
    with FlowClipServer(template_dir, scene_dir, tmp_path, extra_args=["--batch-command", "none"]) as s:
        c = s.client()
        c.observers.append(openapi.observe)
        listed = c.jobs()
        assert listed["available"] is False and listed["jobs"] == []
        sid = c.create_session(scene="drop2d")["id"]
        with pytest.raises(ApiError) as e:
            c.submit_job(sid, frames=1)
        assert e.value.status == 503 and "flowclip-batch" in e.value.message
