"""Batch outputs at fsspec URLs and workers on Kubernetes (clients/python/flowclip/storage.py,
batch.py, docs/batch.md): a wedge written to a file:// URL by a real LocalCluster of 2 worker
processes is complete exactly when each task's task.json is there; an upload interrupted part way
leaves no complete task and a re-run completes it; a URL whose file system is missing or not shared
is refused naming the package; `kind: kubernetes` becomes dask-kubernetes' KubeCluster arguments
(no Kubernetes cluster here: the class is replaced).
"""

from __future__ import annotations

import inspect
import json
import subprocess
import sys
import types

import h5py
import numpy as np
import pytest
from fsspec.implementations.local import LocalFileSystem

from flowclip import batch, storage
from flowclip.batch import SpecError, check_cluster, load_spec, make_cluster, plan, run_batch
from repo_paths import FLOWCLIP_BIN, ROOT
from test_batch import frames_of

FRAMES = 12
FILES = ["frames.h5", "scene.json", "stats.json", "task.json"]


def write_spec(tmp_path, out, **extra):
    spec = {"scene": str(ROOT / "scenes" / "drop2d.json"), "templates": str(ROOT / "templates"),
            "frames": FRAMES, "out": out, "threads": 1, "grid": {"instances[drop].speed": [0.75, 1.5]}}
    spec.update(extra)
    path = tmp_path / "wedge.json"
    path.write_text(json.dumps(spec))
    return path


@pytest.mark.heavy
def test_a_wedge_into_a_file_url_is_complete_task_by_task_and_resumes(tmp_path):
    out = tmp_path / "out"
    spec = load_spec(write_spec(tmp_path, f"file://{out}"))
    results = run_batch(spec, local=2, binary=FLOWCLIP_BIN, log=lambda _: None)
    assert len(results) == 2 and not any(r["skipped"] for r in results)
    # Every task in its folder, task.json among its files; nothing hidden left.
    assert sorted(p.name for p in out.iterdir()) == sorted([r["id"] for r in results] + ["batch.json"])
    for r in results:
        folder = out / r["id"]
        assert sorted(p.name for p in folder.iterdir()) == FILES
        summary = json.loads((folder / "task.json").read_text())
        assert summary["id"] == r["id"] and summary["overrides"] == r["overrides"]
        assert len(json.loads((folder / "stats.json").read_text())["frames"]) == FRAMES
    table = json.loads((out / "batch.json").read_text())
    assert [t["id"] for t in table["tasks"]] == [r["id"] for r in results]
    # A task's frames are those of a plain `flowclip run` of its scene.json.
    first = out / results[0]["id"]
    plain = tmp_path / "plain"
    plain.mkdir()
    (plain / "scene.json").write_bytes((first / "scene.json").read_bytes())
    subprocess.run([str(FLOWCLIP_BIN.resolve()), "run", "scene.json", "--frames", str(FRAMES), "--threads", "1", "--quiet",
                    "--templates", str(ROOT / "templates"), "--export", "frames.h5"], cwd=plain, check=True,
                   timeout=600)
    ours, theirs = frames_of(first / "frames.h5"), frames_of(plain / "frames.h5")
    assert ours.keys() == theirs.keys() and any(k.endswith("position") for k in ours)
    for name in ours:
        assert np.array_equal(ours[name], theirs[name]), name

    # Again: complete tasks (their task.json) are skipped, nothing is rewritten.
    stamps = {r["id"]: (out / r["id"] / "frames.h5").stat().st_mtime_ns for r in results}
    again = run_batch(load_spec(write_spec(tmp_path, f"file://{out}")), local=2, binary=FLOWCLIP_BIN,
                      log=lambda _: None)
    assert [r["id"] for r in again] == [r["id"] for r in results] and all(r["skipped"] for r in again)
    assert stamps == {r["id"]: (out / r["id"] / "frames.h5").stat().st_mtime_ns for r in again}


class Interrupted(OSError):
    pass


@pytest.mark.heavy
@pytest.mark.parametrize("step, after", [("put_file", 2), ("mv", 1)])
def test_an_interrupted_upload_leaves_no_complete_task_and_a_rerun_completes_it(tmp_path, monkeypatch, step,
                                                                                 after):
    """The connection drops after `after` files of the upload (put_file) or of the move into place
    (mv): the task's folder has no task.json, whatever else it has, and the next batch runs it."""
    out = tmp_path / "out"
    spec = load_spec(write_spec(tmp_path, f"file://{out}", grid={"instances[drop].speed": [1.0]}))
    [task] = plan(spec, FLOWCLIP_BIN)
    original = getattr(LocalFileSystem, step)
    calls = []

    def flaky(self, *args, **kwargs):
        calls.append(args)
        if len(calls) > after:
            raise Interrupted("connection reset")
        return original(self, *args, **kwargs)

    monkeypatch.setattr(LocalFileSystem, step, flaky)
    with pytest.raises(Interrupted):
        batch.run_task(task, str(FLOWCLIP_BIN.resolve()))  # here, as a worker runs it
    monkeypatch.setattr(LocalFileSystem, step, original)
    assert len(calls) == after + 1
    assert storage.read_complete(task.folder) is None
    assert not (out / task.id / "task.json").exists()
    if step == "mv":
        assert sorted(p.name for p in (out / task.id).iterdir()) == ["frames.h5"]  # moved before the drop
    # A worker killed mid-upload leaves its hidden folder behind as well.
    dead = out / f".{task.id}.stage-99999-deadbeef"
    dead.mkdir(parents=True)
    (dead / "frames.h5").write_bytes(b"half")

    [result] = run_batch(spec, local=2, binary=FLOWCLIP_BIN, log=lambda _: None)
    assert not result["skipped"] and result["id"] == task.id
    assert sorted(p.name for p in out.iterdir()) == sorted(["batch.json", task.id])
    assert sorted(p.name for p in (out / task.id).iterdir()) == FILES
    assert storage.read_complete(task.folder)["id"] == task.id
    with h5py.File(out / task.id / "frames.h5", "r") as f:
        assert len(f["frames/time"]) == FRAMES + 1


@pytest.mark.parametrize("url, names", [
    ("s3://flowclip-test-bucket/wedge", "needs the s3fs package"),
    ("memory://wedge", "memory:// is each process's own memory"),
    ("nope://wedge", "Protocol not known: nope"),
    ("file:///", "a folder under the file system's root"),
])
def test_a_url_the_workers_cannot_share_is_refused_naming_what_is_missing(tmp_path, url, names):
    if url.startswith("s3:"):
        pytest.importorskip("fsspec")
        if __import__("importlib").util.find_spec("s3fs") is not None:
            pytest.skip("s3fs is installed here")
    with pytest.raises(SpecError) as e:
        plan(load_spec(write_spec(tmp_path, url)), FLOWCLIP_BIN)
    assert str(e.value).startswith("out: ") and names in str(e.value)


def test_a_url_without_fsspec_names_it(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "fsspec", None)
    with pytest.raises(SpecError, match=r"needs fsspec \(pip install \"flowclip\[batch\]\"\)"):
        plan(load_spec(write_spec(tmp_path, "file:///tmp/wedge")), FLOWCLIP_BIN)


def test_url_paths():
    folder = storage.URLPath("s3://bucket/shots/wedge") / "0123abcd"
    assert str(folder) == "s3://bucket/shots/wedge/0123abcd" and folder.name == "0123abcd"
    assert folder.parent == storage.URLPath("s3://bucket/shots/wedge")
    assert storage.is_url("gs://b/x") and storage.is_url(folder) and not storage.is_url("build/batch")
    assert not storage.is_url("/abs/path") and not storage.is_url(ROOT)


def fake_dask_kubernetes(monkeypatch):
    """dask_kubernetes.operator with a KubeCluster that records its arguments and starts nothing."""
    made = []

    class KubeCluster:
        def __init__(self, *, name=None, namespace=None, image=None, n_workers=None, resources=None, env=None,
                     worker_command=None, shutdown_on_close=None, loop=None, asynchronous=False, **kwargs):
            made.append(dict(name=name, namespace=namespace, image=image, n_workers=n_workers, resources=resources,
                             env=env, worker_command=worker_command, **kwargs))

        def close(self):
            pass

    package = types.ModuleType("dask_kubernetes")
    operator = types.ModuleType("dask_kubernetes.operator")
    operator.KubeCluster = KubeCluster
    package.operator = operator
    monkeypatch.setitem(sys.modules, "dask_kubernetes", package)
    monkeypatch.setitem(sys.modules, "dask_kubernetes.operator", operator)
    return made


def test_a_kubernetes_config_becomes_kube_cluster_arguments(monkeypatch):
    made = fake_dask_kubernetes(monkeypatch)
    resources = {"requests": {"cpu": "4", "memory": "8Gi"}, "limits": {"cpu": "4", "memory": "8Gi"}}
    config = {"kind": "kubernetes", "name": "wedge", "namespace": "sim", "image": "registry.example/flowclip-worker:1",
              "jobs": 6, "cores": 4, "resources": resources, "env": {"FSSPEC_S3_ENDPOINT_URL": "http://minio:9000"}}
    make_cluster(config, threads=2)
    assert made == [{"name": "wedge", "namespace": "sim", "image": "registry.example/flowclip-worker:1", "n_workers": 6,
                     "resources": resources, "env": {"FSSPEC_S3_ENDPOINT_URL": "http://minio:9000"},
                     # each worker offers its cores as the resource a task takes `threads` of
                     "worker_command": ["dask", "worker", "--nthreads", "4", "--resources", "cores=4"]}]
    # Defaults: one worker of the spec's threads, named flowclip-batch.
    made.clear()
    make_cluster({"kind": "kubernetes", "image": "flowclip-worker", "n_workers": 3}, threads=2)
    assert made[0]["name"] == "flowclip-batch" and made[0]["n_workers"] == 3
    assert made[0]["worker_command"] == ["dask", "worker", "--nthreads", "2", "--resources", "cores=2"]
    # The command line's check starts nothing.
    made.clear()
    check_cluster(config, threads=2)
    assert made == []


@pytest.mark.parametrize("config, names", [
    ({"kind": "kubernetes", "n_workers": 2}, "image: the workers' image"),
    ({"kind": "kubernetes", "image": "w", "cores": 1}, "cores: the cores of a worker"),
    ({"kind": "kubernetes", "image": "w", "queue": "sim"}, "queue: not an argument of dask-kubernetes' KubeCluster"),
])
def test_a_kubernetes_config_that_cannot_start_is_refused_naming_the_key(monkeypatch, config, names):
    fake_dask_kubernetes(monkeypatch)
    with pytest.raises(SpecError) as e:
        check_cluster(config, threads=2)
    assert names in str(e.value)


def test_kubernetes_without_dask_kubernetes_names_the_package(monkeypatch):
    monkeypatch.setitem(sys.modules, "dask_kubernetes", None)
    monkeypatch.setitem(sys.modules, "dask_kubernetes.operator", None)
    for call in (make_cluster, check_cluster):
        with pytest.raises(SpecError, match=r"kind: kubernetes needs dask-kubernetes \(pip install "):
            call({"kind": "kubernetes", "image": "flowclip-worker"}, 1)


def test_the_documented_kubernetes_keys_are_kube_cluster_arguments():
    """Against the installed dask-kubernetes, when there is one: the keys docs/batch.md shows."""
    operator = pytest.importorskip("dask_kubernetes.operator")
    cls, args = batch.kubernetes_arguments({"kind": "kubernetes", "name": "wedge", "namespace": "sim",
                                            "image": "flowclip-worker:latest", "n_workers": 4, "cores": 2,
                                            "resources": {"limits": {"cpu": "2", "memory": "4Gi"}},
                                            "env": {"OMP_PROC_BIND": "false"}}, threads=1)
    assert cls is operator.KubeCluster
    inspect.signature(cls.__init__).bind(None, **args)
