"""Batch runs on a Dask cluster (clients/python/flowclip/batch.py, docs/batch.md): a wedge of
drop2d on a real LocalCluster of 2 worker processes gives, task by task, the frames and statistics
of a plain `flowclip run` of the same scene bit for bit; a re-run runs nothing; a spec that cannot
run is refused before anything is submitted, naming the key.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading

import h5py
import numpy as np
import pytest

from flowclip.batch import SpecError, export_frames, load_spec, make_cluster, plan, run_batch, set_path
from repo_paths import FLOWCLIP_BIN, ROOT
from service_helpers import wait_until

FRAMES = 12


def write_spec(tmp_path, **extra):
    spec = {"scene": str(ROOT / "scenes" / "drop2d.json"), "templates": str(ROOT / "templates"),
            "frames": FRAMES, "out": str(tmp_path / "out"), "threads": 1,
            "grid": {"instances[drop].speed": [0.75, 1.5], "instances[drop].start": [0.0, 0.05, 0.1]}}
    spec.update(extra)
    path = tmp_path / "wedge.json"
    path.write_text(json.dumps(spec))
    return path


def frames_of(path):
    with h5py.File(path, "r") as f:
        out = {}
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None)
        return out


@pytest.mark.heavy
def test_a_wedge_on_a_local_cluster_equals_plain_runs_and_resumes(tmp_path):
    spec = load_spec(write_spec(tmp_path))
    lines = []
    results = run_batch(spec, local=2, binary=FLOWCLIP_BIN, log=lines.append)
    assert len(results) == 6 and not any(r["skipped"] for r in results)
    assert len({r["id"] for r in results}) == 6
    done = [line for line in lines if line.startswith("batch: ")]
    assert len(done) == 6 and done[-1].startswith("batch: 6/6 ")
    # Each task's own progress, from its flowclip's frame lines, reaches the client as it runs.
    progress = [line for line in lines if line.startswith("task ")]
    assert progress and all(line.split(": frame ")[1].split()[0].split("/")[1] == str(FRAMES) for line in progress)
    assert any(line.endswith(f": frame {FRAMES}/{FRAMES} [{'#' * 20}] 100%") for line in progress)
    assert len(progress) <= 6 * FRAMES  # at most one report per frame line of each task
    table = json.loads((tmp_path / "out" / "batch.json").read_text())
    assert [t["id"] for t in table["tasks"]] == [r["id"] for r in results]
    speeds = set()
    for r in results:
        folder = tmp_path / "out" / r["id"]
        assert sorted(p.name for p in folder.iterdir()) == ["frames.h5", "scene.json", "stats.json", "task.json"]
        scene = json.loads((folder / "scene.json").read_text())
        drop = scene["instances"][0]
        assert drop["speed"] == r["overrides"]["instances[drop].speed"]
        assert drop["start"] == r["overrides"]["instances[drop].start"]
        speeds.add(drop["speed"])
        # The same scene run plainly, here: the same frames bit for bit, the same statistics.
        plain = tmp_path / f"plain-{r['id']}"
        plain.mkdir()
        (plain / "scene.json").write_text(json.dumps(scene))
        subprocess.run([str(FLOWCLIP_BIN), "run", "scene.json", "--frames", str(FRAMES), "--threads", "1",
                        "--quiet", "--templates", str(ROOT / "templates"), "--export", "frames.h5",
                        "--stats", "stats.json"], cwd=plain, check=True, timeout=600)
        ours, theirs = frames_of(folder / "frames.h5"), frames_of(plain / "frames.h5")
        assert ours.keys() == theirs.keys() and any(k.endswith("position") for k in ours)
        for name in ours:
            assert np.array_equal(ours[name], theirs[name]), f"{r['id']}: {name} differs"
        a = json.loads((folder / "stats.json").read_text())
        b = json.loads((plain / "stats.json").read_text())
        assert len(a["frames"]) == len(b["frames"]) == FRAMES
        for fa, fb in zip(a["frames"], b["frames"]):
            for key in ("particles", "substeps", "density_iterations", "divergence_iterations"):
                assert fa[key] == fb[key], f"{r['id']} frame {fa.get('frame')}: {key}"
    assert speeds == {0.75, 1.5}
    # Different instances' timing: the wedge's takes are not all the same liquid.
    finals = {r["id"]: frames_of(tmp_path / "out" / r["id"] / "frames.h5") for r in results}
    positions = [next(v for k, v in f.items() if k.endswith("position")) for f in finals.values()]
    assert any(not np.array_equal(positions[0], p) for p in positions[1:])

    # Again: everything is complete, nothing runs, nothing is rewritten.
    stamps = {r["id"]: (tmp_path / "out" / r["id"] / "frames.h5").stat().st_mtime_ns for r in results}
    again = run_batch(load_spec(write_spec(tmp_path)), local=2, binary=FLOWCLIP_BIN, log=lambda _: None)
    assert [r["id"] for r in again] == [r["id"] for r in results] and all(r["skipped"] for r in again)
    assert stamps == {r["id"]: (tmp_path / "out" / r["id"] / "frames.h5").stat().st_mtime_ns for r in again}


def test_a_killed_tasks_leftovers_never_count_as_complete(tmp_path):
    spec = load_spec(write_spec(tmp_path, grid={"instances[drop].speed": [1.0]}))
    [task] = plan(spec, FLOWCLIP_BIN)
    out = tmp_path / "out"
    # A worker killed mid-task left a hidden, half-written folder.
    half = out / f".{task.id}.stage-99999-deadbeef"
    half.mkdir(parents=True)
    (half / "frames.h5").write_bytes(b"half")
    [result] = run_batch(spec, local=1, binary=FLOWCLIP_BIN, log=lambda _: None)
    assert not result["skipped"] and not half.exists()
    assert (out / task.id / "task.json").exists()


@pytest.mark.heavy
def test_a_worker_killed_mid_task_is_retried_and_leaves_nothing_partial(tmp_path):
    spec = load_spec(write_spec(tmp_path, frames=200, grid={"instances[drop].speed": [1.0, 2.0]}))
    out = tmp_path / "out"
    killed = []

    def running_task():
        return next((f for f in (out.glob(".*.stage-*") if out.exists() else []) if (f / "scene.json").exists()),
                    None)

    def kill_a_worker_mid_task():
        # A task's hidden folder carries its worker's pid: SIGKILL that worker once the task runs.
        try:
            folder = wait_until(running_task, timeout=600, what="a task running")
        except TimeoutError:
            return  # the assertion below says so
        pid = int(folder.name.split(".stage-")[1].split("-")[0])
        os.kill(pid, signal.SIGKILL)
        killed.append(pid)

    killer = threading.Thread(target=kill_a_worker_mid_task)
    killer.start()
    results = run_batch(spec, local=2, binary=FLOWCLIP_BIN, log=lambda _: None)
    killer.join()
    assert killed, "no task was caught running"
    assert len(results) == 2 and not any(r["skipped"] for r in results)
    # Both tasks whole, and nothing else: no hidden half-written folder.
    assert sorted(p.name for p in out.iterdir()) == sorted([r["id"] for r in results] + ["batch.json"])
    for r in results:
        stats = json.loads((out / r["id"] / "stats.json").read_text())
        assert len(stats["frames"]) == 200
        with h5py.File(out / r["id"] / "frames.h5", "r") as f:
            assert len(f["frames/time"]) == 201  # the initial state and 200 frames


@pytest.mark.parametrize("change, names", [
    ({"color": 1}, "color: unknown key of a job spec"),
    ({"grid": {"instances[rain].speed": [1]}}, "no element of instances named 'rain'"),
    ({"grid": {"instances[drop].sped": [1]}}, "instances[0].sped: unknown parameter of an instance"),
    ({"grid": {"particle_radius": [0.01, -1]}}, "particle_radius: -1 m must be > 0"),
    ({"list": [{"instances[drop].template": "nope"}]}, "instances[0].template: no template 'nope'"),
    ({"grid": {"domain.min[7]": [0]}}, "domain.min has 2 elements"),
    ({"frames": -3}, "frames: a number >= 0"),
    ({"grid": {}, "list": [{"instances[drop].speed": 1}, {"instances[drop].speed": 1}]},
     'the same task as {"instances[drop].speed": 1} (a value given twice)'),
])
def test_a_spec_that_cannot_run_is_refused_before_anything_runs(tmp_path, change, names):
    spec = load_spec(write_spec(tmp_path, **change)) if "color" not in change else None
    if spec is None:
        with pytest.raises(SpecError, match="color: unknown key"):
            load_spec(write_spec(tmp_path, **change))
        return
    with pytest.raises(SpecError) as e:
        plan(spec, FLOWCLIP_BIN)
    assert names in str(e.value)
    assert not (tmp_path / "out").exists()


def test_the_command_line_checks_and_lists_the_tasks(tmp_path):
    path = write_spec(tmp_path)
    r = subprocess.run([sys.executable, "-m", "flowclip.batch", "run", str(path), "--dry-run", "--binary",
                        str(FLOWCLIP_BIN)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert len(r.stdout.splitlines()) == 6 and not (tmp_path / "out").exists()
    bad = write_spec(tmp_path, grid={"particle_radius": [-1]})
    r = subprocess.run([sys.executable, "-m", "flowclip.batch", "run", str(bad), "--binary", str(FLOWCLIP_BIN)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "particle_radius: -1 m must be > 0" in r.stderr


def test_a_batch_whose_starter_dies_stops_with_everything_it_started(tmp_path):
    """--watch-stdin: when the program that started the batch (the server) dies, its stdin closes and
    the batch, its LocalCluster's workers and their flowclip runs all stop; nothing is left running."""
    path = write_spec(tmp_path, grid={"instances[drop].speed": [1.0, 2.0]}, frames=100000)
    proc = subprocess.Popen([sys.executable, "-m", "flowclip.batch", "run", str(path), "--local", "2", "--binary",
                             str(FLOWCLIP_BIN), "--progress", "json", "--watch-stdin"], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, start_new_session=True)
    events = []
    try:
        for line in proc.stdout:  # until a task reports a frame: the flowclip runs are going
            events.append(json.loads(line))
            if events[-1]["event"] == "task":
                break
        assert [e["event"] for e in events][0] == "plan" and events[-1]["event"] == "task", events
        group = proc.pid  # its own session: the batch's processes are this group's
        members = lambda: [p for p in os.listdir("/proc") if p.isdigit() and _group_of(p) == group]
        assert len(members()) >= 4  # the batch, two workers (and their nanny), a flowclip run
        proc.stdin.close()  # as if the server had died
        assert proc.wait(timeout=120) != 0
        wait_until(lambda: not members(), timeout=120, what="every process of the batch gone")
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)


def _group_of(pid):
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return int(fields[2]) if fields[0] != "Z" else None
    except (OSError, IndexError, ValueError):
        return None


def test_a_worker_without_the_clients_flowclip_runs_its_own(tmp_path, monkeypatch):
    """The task names the client's executable; a worker (an image) that lacks that path runs its own
    flowclip ($FLOWCLIP_BIN), and the task's frames are the same."""
    from flowclip.batch import run_task

    spec = load_spec(write_spec(tmp_path, grid={"instances[drop].speed": [1.0]}, frames=3))
    (task,) = plan(spec, FLOWCLIP_BIN)
    (tmp_path / "out").mkdir()
    monkeypatch.setenv("FLOWCLIP_BIN", str(FLOWCLIP_BIN))
    result = run_task(task, str(tmp_path / "not-on-this-worker" / "flowclip"))
    assert not result["skipped"] and result["summary"]["frames"] == 3
    assert (tmp_path / "out" / task.id / "frames.h5").exists()


def test_the_summary_table_lists_every_task():
    from flowclip.batch import summary_table

    table = summary_table([
        {"id": "aaa", "overrides": {"instances[drop].speed": 0.5}, "skipped": False, "wall_s": 3.25,
         "summary": {"frames": 12, "ms_per_frame": 20.04}},
        {"id": "bbb", "overrides": {}, "skipped": True, "wall_s": 1.0, "summary": {"frames": 12}},
    ]).splitlines()
    assert table[0].split() == ["task", "overrides", "wall", "s", "frames", "ms/frame"]
    assert table[1].split() == ["aaa", '{"instances[drop].speed":', "0.5}", "run", "3.2", "12", "20.0"]
    assert table[2].split() == ["bbb", "-", "skipped", "1.0", "12"]


def test_key_paths():
    scene = {"a": {"b": [1, 2]}, "items": [{"name": "x", "v": 1}, {"name": "y", "v": 2}]}
    set_path(scene, "items[y].v", 5)
    set_path(scene, "a.b[1]", 7)
    set_path(scene, "items[0].w", 3)
    assert scene == {"a": {"b": [1, 7]}, "items": [{"name": "x", "v": 1, "w": 3}, {"name": "y", "v": 5}]}
    for bad in ("", "a..b", "[0]", "a.b]", "a.missing.c"):
        with pytest.raises(SpecError):
            set_path(scene, bad, 1)


def test_a_frame_parallel_export_equals_one_export(tmp_path):
    """Frame ranges meshed on two workers and put together: the files of one `flowclip export`."""
    h5 = tmp_path / "drop.h5"
    subprocess.run([str(FLOWCLIP_BIN), "run", str(ROOT / "scenes" / "drop2d.json"), "--frames", "9", "--quiet",
                    "--templates", str(ROOT / "templates"), "--export", str(h5)], check=True, timeout=600)
    formats = ["ply", "points", "obj", "usd"]
    parallel, single = tmp_path / "parallel", tmp_path / "single"
    lines = []
    manifest = export_frames(h5, parallel, formats, name="shot", chunk=3, local=2, binary=FLOWCLIP_BIN,
                             log=lines.append)
    assert lines[-1] == "export: 5/5 parts"  # frames 0-9 in four ranges, and the USD stage
    subprocess.run([str(FLOWCLIP_BIN), "export", str(h5), "--out", str(single), "--name", "shot", "--formats",
                    ",".join(formats), "--quiet"], check=True, timeout=600)
    names = sorted(p.name for p in single.iterdir())
    assert sorted(p.name for p in parallel.iterdir()) == names  # nothing hidden left behind
    assert len([n for n in names if n.endswith(".obj")]) == 10
    for n in names:
        if n.endswith(".export.json"):
            continue
        assert (parallel / n).read_bytes() == (single / n).read_bytes(), n
    one = json.loads((single / "shot.export.json").read_text())
    ours = json.loads((parallel / "shot.export.json").read_text())
    assert ours == manifest
    assert ours["frames"] == one["frames"] and ours["files"] == one["files"] and ours["formats"] == one["formats"]


@pytest.mark.parametrize("kind, lines", [
    ("slurm", ["#SBATCH -p sim", "#SBATCH --cpus-per-task=4", "#SBATCH -t 02:00:00"]),
    ("pbs", ["#PBS -q sim", "#PBS -l walltime=02:00:00"]),
])
def test_a_cluster_config_becomes_batch_system_jobs(kind, lines):
    """The job script a batch system would run: the config's queue, cores and time, and workers that
    offer their cores as the resource each task takes the spec's threads of."""
    cluster = make_cluster({"kind": kind, "jobs": 3, "cores": 4, "memory": "8GB", "walltime": "02:00:00",
                            "queue": "sim"}, threads=2)
    try:
        script = cluster.job_script()
    finally:
        cluster.close()
    for line in lines:
        assert line in script
    assert "--resources cores=4" in script and "--nthreads 4" in script


@pytest.mark.parametrize("config, names", [
    ({"kind": "yarn", "cores": 2}, "kind: 'yarn' is not one of"),
    ({"kind": "slurm", "cores": 1, "memory": "1GB"}, "cores: the cores of a job"),
    ({"kind": "slurm", "cores": 4, "memory": "1GB", "colour": "red"}, "colour"),
])
def test_a_cluster_config_that_cannot_start_is_refused_naming_the_key(config, names):
    with pytest.raises(SpecError) as e:
        make_cluster(config, threads=2)
    assert names in str(e.value)
