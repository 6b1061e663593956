"""`flowclip-batch`: many runs of one scene, each with its own overrides (a wedge), as tasks of a
Dask distributed cluster: a LocalCluster on one machine, or any scheduler's address.

A job spec (JSON or YAML, docs/batch.md):

    scene: scenes/drop2d.json          # relative to the spec's folder
    templates: templates               # the template database the workers read
    frames: 60                         # or seconds: 1.0 (default: the scene's duration)
    grid:                              # every combination
      "instances[drop].speed": [0.5, 1, 2]
      "instances[drop].start": [0.1, 0.3]
    list:                              # and/or these, one task each
      - {particle_radius: 0.008}
    outputs: {frames: true, surface: [ply]}
    out: build/batch/drop-wedge        # one folder per task, named by a hash of its inputs
    threads: 1                         # OpenMP threads per task

`--cluster FILE` starts the workers as jobs of a batch system instead (dask-jobqueue: Slurm, PBS,
SGE, LSF, HTCondor, OAR, Moab): `kind`, `jobs`, and the jobqueue class's own arguments; or as pods of
a Kubernetes cluster (`kind: kubernetes`, dask-kubernetes' operator).
`out` may be a URL (s3://, gs://, file://...) that fsspec opens: flowclip.storage.

A key path names a scene key: `a.b`, `list[NAME]` (the element whose "name" is NAME) or `list[3]`.
Every task's scene is checked by `flowclip run --frames 0` before anything is submitted, so an
unknown key, a value out of range or a missing template stops the batch naming the key. A task
writes into a hidden folder renamed into place when it is whole: a re-run skips the tasks whose
folders exist, and a task whose worker dies is retried elsewhere without its partial files.
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import inspect
import itertools
import json
import os
import re
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from flowclip import storage

SPEC_KEYS = {"scene", "templates", "frames", "seconds", "grid", "list", "outputs", "out", "threads", "name"}
OUTPUT_KEYS = {"stats", "frames", "surface"}


class SpecError(ValueError):
    """A job spec that cannot run; the message names the key."""


@dataclass
class Task:
    id: str
    overrides: dict
    scene: dict
    folder: Path
    args: list = field(default_factory=list)  # `flowclip run` arguments after the scene file


def _binary(binary=None) -> str:
    found = binary or os.environ.get("FLOWCLIP_BIN") or shutil.which("flowclip")
    if not found or not Path(found).exists():
        raise SpecError("no flowclip executable: pass --binary, set FLOWCLIP_BIN or put flowclip on PATH")
    return str(Path(found).resolve())


_TOKEN = re.compile(r"([^.\[\]]+)|\[([^\]]*)\]")


def _tokens(path: str) -> list:
    pos, out = 0, []
    for m in _TOKEN.finditer(path):
        if m.start() != pos and path[pos:m.start()] != ".":
            raise SpecError(f"{path}: not a key path (a.b, list[NAME], list[3])")
        out.append(("key", m.group(1)) if m.group(1) is not None else ("item", m.group(2)))
        pos = m.end()
    if pos != len(path) or not out or out[0][0] != "key":
        raise SpecError(f"{path}: not a key path (a.b, list[NAME], list[3])")
    return out


def set_path(scene: dict, path: str, value) -> None:
    """Sets the key `path` of `scene`; every container on the way must exist (the last key may be new)."""
    tokens = _tokens(path)
    node, where = scene, ""
    for n, (kind, name) in enumerate(tokens):
        last = n == len(tokens) - 1
        if kind == "key":
            if not isinstance(node, dict):
                raise SpecError(f"{path}: {where or 'the scene'} is not an object")
            if last:
                node[name] = value
                return
            if name not in node:
                raise SpecError(f"{path}: the scene has no {where + '.' if where else ''}{name}")
            node, where = node[name], f"{where}.{name}" if where else name
        else:
            if not isinstance(node, list):
                raise SpecError(f"{path}: {where} is not a list")
            if name.isdigit():
                index = int(name)
                if index >= len(node):
                    raise SpecError(f"{path}: {where} has {len(node)} elements")
            else:
                matches = [i for i, e in enumerate(node) if isinstance(e, dict) and e.get("name") == name]
                if not matches:
                    names = [e.get("name") for e in node if isinstance(e, dict) and "name" in e]
                    raise SpecError(f"{path}: no element of {where} named {name!r} (names: {names})")
                index = matches[0]
            if last:
                node[index] = value
                return
            node, where = node[index], f"{where}[{name}]"


def load_spec(path) -> dict:
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise SpecError(f"{path}: {e.strerror}") from None
    try:
        if path.suffix in (".yaml", ".yml"):
            import yaml
            spec = yaml.safe_load(text)
        else:
            spec = json.loads(text)
    except Exception as e:  # the parser's own message says where
        raise SpecError(f"{path}: not valid {'YAML' if path.suffix in ('.yaml', '.yml') else 'JSON'}: {e}") from None
    if not isinstance(spec, dict):
        raise SpecError(f"{path}: a job spec is an object")
    unknown = sorted(set(spec) - SPEC_KEYS)
    if unknown:
        raise SpecError(f"{unknown[0]}: unknown key of a job spec; expected one of: {', '.join(sorted(SPEC_KEYS))}")
    spec["_dir"] = str(path.resolve().parent)
    return spec


def plan(spec: dict, binary=None) -> list[Task]:
    """The tasks of a spec, each checked by the executable; SpecError at the first that cannot run."""
    base = Path(spec.get("_dir", "."))
    if "scene" not in spec:
        raise SpecError("scene: a job spec needs a scene file")
    scene_path = (base / spec["scene"]).resolve()
    try:
        scene = json.loads(scene_path.read_text())
    except (OSError, ValueError) as e:
        raise SpecError(f"scene: cannot read {scene_path}: {e}") from None
    if "frames" in spec and "seconds" in spec:
        raise SpecError("frames: give frames or seconds, not both")
    outputs = spec.get("outputs", {"stats": True, "frames": True})
    if not isinstance(outputs, dict) or set(outputs) - OUTPUT_KEYS:
        raise SpecError(f"outputs: an object of {', '.join(sorted(OUTPUT_KEYS))}")
    grid = spec.get("grid", {})
    if not isinstance(grid, dict) or not all(isinstance(v, list) and v for v in grid.values()):
        raise SpecError("grid: an object of key path -> non-empty list of values")
    variations = [dict(zip(grid, values)) for values in itertools.product(*grid.values())] if grid else []
    listed = spec.get("list", [])
    if not isinstance(listed, list) or not all(isinstance(v, dict) for v in listed):
        raise SpecError("list: a list of objects of key path -> value")
    variations += listed
    if not variations:
        variations = [{}]
    threads = spec.get("threads", 1)
    if not isinstance(threads, int) or threads < 1:
        raise SpecError("threads: a positive integer")
    args = []
    for key in ("frames", "seconds"):
        if key in spec:
            value = spec[key]
            if not isinstance(value, (int, float)) or isinstance(value, bool) or value < 0:
                raise SpecError(f"{key}: a number >= 0")
            args += [f"--{key}", str(value)]
    args += ["--threads", str(threads), "--quiet"]
    surface = outputs.get("surface") or []
    if surface:
        args += ["--formats", ",".join(surface)]
    templates = str((base / spec.get("templates", "templates")).resolve())
    out = spec.get("out", "batch")
    out = storage.output(out) if storage.is_url(out) else (base / out).resolve()
    exe = _binary(binary)
    version = subprocess.run([exe, "--version"], capture_output=True, text=True, timeout=60).stdout.strip()
    tasks = []
    for overrides in variations:
        task_scene = copy.deepcopy(scene)
        for path, value in overrides.items():
            set_path(task_scene, path, value)
        key = json.dumps({"scene": task_scene, "args": args, "outputs": outputs, "flowclip": version},
                         sort_keys=True, separators=(",", ":"))
        tid = hashlib.sha256(key.encode()).hexdigest()[:16]
        twin = next((t for t in tasks if t.id == tid), None)
        if twin is not None:  # one folder, one result: the same run twice is a mistake in the spec
            raise SpecError(f"{json.dumps(overrides)}: the same task as {json.dumps(twin.overrides)} (a value given twice)")
        tasks.append(Task(tid, overrides, task_scene, out / tid, list(args)))
    # The executable's own checks: every key, range and template, before anything runs.
    with tempfile.TemporaryDirectory(prefix="flowclip-batch-") as tmp:
        for task in tasks:
            f = Path(tmp) / f"{task.id}.json"
            f.write_text(json.dumps(task.scene))
            r = subprocess.run([exe, "run", str(f), "--frames", "0", "--quiet", "--templates", templates],
                               capture_output=True, text=True, timeout=300)
            if r.returncode != 0:
                message = r.stderr.strip().replace(str(f) + ": ", "")
                raise SpecError(f"{json.dumps(task.overrides) if task.overrides else 'the scene'}: {message}")
    for task in tasks:
        task.args += ["--templates", templates]
        task.args += ["--stats", "stats.json"] if outputs.get("stats", True) else []
        task.args += ["--export", "frames.h5"] if outputs.get("frames", True) else []
        task.args += ["--export-surface", "surface"] if surface else []
    return tasks


def _load_prctl():
    try:
        import ctypes

        return ctypes.CDLL("libc.so.6", use_errno=True).prctl
    except OSError:
        return None


_PRCTL = _load_prctl()  # resolved here: a forked child of a threaded worker must not dlopen


def _die_with_parent() -> None:
    """In the child: killed when the worker that started it dies, so that no orphan keeps writing."""
    if _PRCTL is not None:
        _PRCTL(1, 9)  # PR_SET_PDEATHSIG, SIGKILL


_FRAME = re.compile(r"^frame (\d+)/(\d+)")
PROGRESS_TOPIC = "flowclip-task-progress"


def _report(progress: dict) -> None:
    """A task's progress, to the client that watches the cluster's events (none outside a worker)."""
    try:
        from distributed import get_worker

        get_worker().log_event(PROGRESS_TOPIC, progress)
    except (ImportError, ValueError):
        pass


def _worker_binary(binary: str) -> str:
    """The client's flowclip where the worker has it, else the worker's own ($FLOWCLIP_BIN, PATH):
    a worker image need not share the client's layout."""
    if os.path.exists(binary):
        return binary
    return os.environ.get("FLOWCLIP_BIN") or shutil.which("flowclip") or binary


def run_task(task: Task, binary: str) -> dict:
    """One task on a worker: skipped when its folder exists, else run in a hidden folder that is
    renamed into place whole. A URL's task runs in a local temporary folder, then is uploaded."""
    if storage.is_url(task.folder):
        return storage.run_task(task, binary, run_task)
    done = task.folder / "task.json"
    if done.exists():
        return {**json.loads(done.read_text()), "skipped": True}
    if not task.folder.parent.is_dir():  # run_batch made it: gone means the batch was cancelled
        raise RuntimeError(f"task {task.id}: the output folder {task.folder.parent} was removed")
    staging = task.folder.parent / f".{task.id}.stage-{os.getpid()}-{secrets.token_hex(4)}"
    staging.mkdir()
    try:
        (staging / "scene.json").write_text(json.dumps(task.scene, indent=1))
        t0 = time.monotonic()
        args = [a for a in task.args if a != "--quiet"]  # its per-frame lines are the task's progress
        proc = subprocess.Popen([_worker_binary(binary), "run", "scene.json", *args], cwd=staging, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True, preexec_fn=_die_with_parent)
        tail, reported, last = [], -1.0, 0.0
        for line in proc.stderr:
            tail = (tail + [line.rstrip()])[-20:]
            if not task.folder.parent.is_dir():  # the batch's output was removed: cancelled
                proc.kill()
                proc.wait()
                raise RuntimeError(f"task {task.id}: its output folder {task.folder.parent} was removed")
            m = _FRAME.match(line)
            if m:
                done, total = int(m.group(1)), int(m.group(2))
                # Every tenth of the task and its last frame, and at least every few seconds.
                if done == total or done / total >= reported + 0.1 or time.monotonic() - last > 2:
                    reported, last = done / total, time.monotonic()
                    _report({"id": task.id, "frame": done, "frames": total})
        if proc.wait() != 0:
            message = "\n".join(line for line in tail if not _FRAME.match(line))
            raise RuntimeError(f"task {task.id} {json.dumps(task.overrides)}: flowclip exited with {proc.returncode}: "
                               f"{message[-2000:]}")
        summary = {"id": task.id, "overrides": task.overrides, "wall_s": time.monotonic() - t0,
                   "command": ["flowclip", "run", "scene.json", *task.args]}
        stats = staging / "stats.json"
        if stats.exists():
            summary["summary"] = json.loads(stats.read_text()).get("summary", {})
        (staging / "task.json").write_text(json.dumps(summary, indent=1))
        try:
            staging.rename(task.folder)  # the task is complete exactly when its folder exists
        except OSError:
            if not done.exists():  # not another attempt's complete folder
                raise
        return {**summary, "skipped": False}
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)


# A cluster started on a batch system (dask-jobqueue): the config's `kind`, the class that starts it.
JOBQUEUE = {"slurm": "SLURMCluster", "pbs": "PBSCluster", "sge": "SGECluster", "lsf": "LSFCluster",
            "htcondor": "HTCondorCluster", "oar": "OARCluster", "moab": "MoabCluster"}


def load_cluster_config(path) -> dict:
    """A cluster config file (JSON or YAML): kind, jobs, and the dask-jobqueue class's own arguments."""
    path = Path(path)
    try:
        text = path.read_text()
        import yaml
        config = yaml.safe_load(text) if path.suffix in (".yaml", ".yml") else json.loads(text)
    except OSError as e:
        raise SpecError(f"{path}: {e.strerror}") from None
    except Exception as e:
        raise SpecError(f"{path}: not a valid cluster config: {e}") from None
    if not isinstance(config, dict):
        raise SpecError(f"{path}: a cluster config is an object")
    return config


def kubernetes_arguments(config: dict, threads: int = 1) -> tuple:
    """dask-kubernetes' KubeCluster and its arguments for a `kind: kubernetes` config: the config's
    own keys (name, namespace, image, n_workers or jobs, resources, env...), and workers that offer
    `cores` (default: the spec's threads) as the resource a task takes `threads` of."""
    try:
        from dask_kubernetes.operator import KubeCluster
    except ImportError:
        raise SpecError('kind: kubernetes needs dask-kubernetes (pip install "flowclip[batch,kubernetes]")') from None
    args = {k: v for k, v in config.items() if k != "kind"}
    jobs = args.pop("jobs", None)
    if jobs is not None:
        args.setdefault("n_workers", jobs)
    cores = args.pop("cores", threads)
    if not isinstance(cores, int) or isinstance(cores, bool) or cores < threads:
        raise SpecError(f"cores: the cores of a worker, an integer of at least the spec's threads ({threads})")
    if not args.get("image"):
        raise SpecError("image: the workers' image (docker build --target worker), in a registry the cluster pulls from")
    known = {name for name, p in inspect.signature(KubeCluster.__init__).parameters.items()
             if p.kind is p.KEYWORD_ONLY} - {"loop", "asynchronous"}
    for key in sorted(args):
        if key not in known:
            raise SpecError(f"{key}: not an argument of dask-kubernetes' KubeCluster ({', '.join(sorted(known))})")
    command = args.get("worker_command") or ["dask", "worker"]
    command = command.split() if isinstance(command, str) else list(command)
    args["worker_command"] = command + ["--nthreads", str(cores), "--resources", f"cores={cores}"]
    args.setdefault("name", "flowclip-batch")
    args.setdefault("n_workers", 1)
    return KubeCluster, args


def check_cluster(config: dict, threads: int = 1) -> None:
    """SpecError naming the key of a config that cannot start; starts nothing on Kubernetes."""
    if config.get("kind") == "kubernetes":
        kubernetes_arguments(config, threads)
    else:
        make_cluster(config, threads).close()


def make_cluster(config: dict, threads: int = 1):
    """The cluster a config describes, not yet scaled: a dask-jobqueue cluster whose workers each
    offer `cores` (the config's cores over its processes) as the resource a task takes `threads` of;
    for `kind: kubernetes`, a KubeCluster started with its n_workers."""
    if config.get("kind") == "kubernetes":
        cls, args = kubernetes_arguments(config, threads)
        return cls(**args)
    config = dict(config)
    kind = config.pop("kind", None)
    config.pop("jobs", None)
    if kind not in JOBQUEUE:
        raise SpecError(f"kind: {kind!r} is not one of {', '.join(sorted([*JOBQUEUE, 'kubernetes']))}")
    try:
        import dask_jobqueue
    except ImportError:
        raise SpecError(f"kind: {kind} needs dask-jobqueue (pip install \"flowclip[batch]\")") from None
    if "cores" not in config or not isinstance(config["cores"], int) or config["cores"] < threads:
        raise SpecError(f"cores: the cores of a job, an integer of at least the spec's threads ({threads})")
    processes = config.setdefault("processes", 1)
    per_worker = config["cores"] // max(1, processes)
    config["worker_extra_args"] = list(config.get("worker_extra_args", [])) + ["--resources", f"cores={per_worker}"]
    config.setdefault("scheduler_options", {"dashboard_address": None})
    try:
        return getattr(dask_jobqueue, JOBQUEUE[kind])(**config)
    except (TypeError, ValueError) as e:  # an argument the class does not take
        m = re.search(r"argument '(\w+)'", str(e))
        raise SpecError(f"{m.group(1) if m else kind}: not an argument of dask-jobqueue's {JOBQUEUE[kind]}: "
                        f"{str(e).splitlines()[0]}") from None


def _bar(fraction: float, width: int = 20) -> str:
    filled = int(round(max(0.0, min(1.0, fraction)) * width))
    return "[" + "#" * filled + "." * (width - filled) + f"] {100 * fraction:3.0f}%"


def summary_table(results: list[dict]) -> str:
    """The batch's tasks as a text table: id, overrides, run or skipped, wall s, frames, ms per frame."""
    rows = [("task", "overrides", "", "wall s", "frames", "ms/frame")]
    for r in results:
        s = r.get("summary", {})
        rows.append((r["id"], json.dumps(r["overrides"]) if r["overrides"] else "-",
                     "skipped" if r["skipped"] else "run", f"{r.get('wall_s', 0):.1f}",
                     str(s.get("frames", "")), f"{s['ms_per_frame']:.1f}" if "ms_per_frame" in s else ""))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip() for row in rows)


def run_batch(spec: dict, *, local=None, scheduler=None, cluster_config=None, binary=None, retries=2,
              log=print, event=None) -> list[dict]:
    """Plans the spec, then runs its tasks on the cluster; the summaries in the spec's order.
    `event(dict)` receives the batch's progress as data: plan, task (frames), done."""
    event = event or (lambda e: None)
    tasks = plan(spec, binary)
    event({"event": "plan", "out": str(tasks[0].folder.parent),
           "tasks": [{"id": t.id, "overrides": t.overrides} for t in tasks]})
    exe = _binary(binary)
    out = tasks[0].folder.parent
    remote = storage.is_url(out)
    if remote:
        storage.prepare(out)
    else:
        out.mkdir(parents=True, exist_ok=True)
    def remove_leftovers():  # a killed worker's hidden folders: never complete
        if remote:
            return storage.remove_stages(out)
        for left in out.glob(".*.stage-*"):
            shutil.rmtree(left, ignore_errors=True)

    remove_leftovers()
    from distributed import Client, LocalCluster, as_completed

    resources = None
    if cluster_config is not None:  # a batch system's jobs, each task taking `threads` of a worker's cores
        threads = spec.get("threads", 1)
        cluster = make_cluster(cluster_config, threads)
        if cluster_config.get("kind") != "kubernetes":  # a KubeCluster starts its n_workers itself
            cluster.scale(jobs=cluster_config.get("jobs", 1))
        resources = {"cores": threads}
    elif scheduler is None:
        cluster = LocalCluster(n_workers=local, threads_per_worker=1, processes=True, dashboard_address=None)
    else:
        cluster = None
    try:
        with Client(cluster if cluster is not None else scheduler) as client:
            ids = {t.id for t in tasks}

            def progress(logged):
                message = logged[1] if isinstance(logged, tuple) else logged
                if isinstance(message, dict) and message.get("id") in ids:
                    log(f"task {message['id']}: frame {message['frame']}/{message['frames']} "
                        f"{_bar(message['frame'] / max(1, message['frames']))}")
                    event({"event": "task", **message})

            client.subscribe_topic(PROGRESS_TOPIC, progress)
            futures = [client.submit(run_task, t, exe, key=f"flowclip-task-{t.id}", pure=False, retries=retries,
                                     resources=resources) for t in tasks]
            index = {f.key: n for n, f in enumerate(futures)}
            results = [None] * len(tasks)
            for done, future in enumerate(as_completed(futures), 1):
                result = future.result()
                results[index[future.key]] = result
                state = "skipped (complete)" if result["skipped"] else f"{result['wall_s']:.1f} s"
                log(f"batch: {done}/{len(tasks)} {_bar(done / len(tasks))} {result['id']} "
                    f"{json.dumps(result['overrides'])} {state}")
                event({"event": "done", **result})
    finally:
        if cluster is not None:
            cluster.close()
    remove_leftovers()  # every task is over: what is hidden is a dead attempt's
    table = {"spec": {k: v for k, v in spec.items() if not k.startswith("_")}, "tasks": results}
    if remote:  # written once every task's task.json is in place
        storage.write_table(out, [t.folder for t in tasks], table)
        return results
    staged = out / f".batch.json.{os.getpid()}"
    staged.write_text(json.dumps(table, indent=1))
    staged.replace(out / "batch.json")
    return results


def _export_part(binary: str, frames_file: str, stage: str, name: str, first: int, last: int | None,
                 formats: list, options: list) -> dict:
    """One part of a frame-parallel export on a worker: `flowclip export` of frames first..last into
    its own hidden folder; returns that part's manifest."""
    cmd = [_worker_binary(binary), "export", frames_file, "--out", stage, "--name", name, "--formats", ",".join(formats),
           "--threads", "1", "--quiet", *options, "--first", str(first)]
    if last is not None:
        cmd += ["--last", str(last)]
    r = subprocess.run(cmd, capture_output=True, text=True, preexec_fn=_die_with_parent)
    if r.returncode != 0:
        raise RuntimeError(f"flowclip export of frames {first}-{last}: exit {r.returncode}: {r.stderr.strip()[-2000:]}")
    return json.loads((Path(stage) / f"{name}.export.json").read_text())


def export_frames(frames_file, out, formats, *, name=None, surface=(), format_settings=(), chunk=None, local=None,
                  scheduler=None, binary=None, log=print) -> dict:
    """`flowclip export` split into frame ranges across a cluster's workers, put together in order:
    the same files as one `flowclip export`, and one manifest, written last (the export is complete
    exactly when NAME.export.json exists). A USD stage holds every frame, so it is one task of its own."""
    import h5py
    from distributed import Client, LocalCluster, as_completed

    exe = _binary(binary)
    frames_file = str(Path(frames_file).resolve())
    name = name or Path(frames_file).stem
    out = Path(out).resolve()
    with h5py.File(frames_file, "r") as f:
        numbers = [int(i) for i in f["frames/index"][()]]
    if not numbers:
        raise SpecError(f"{frames_file}: no frames")
    options = [a for kv in surface for a in ("--surface", kv)] + [a for kv in format_settings for a in ("--format-setting", kv)]
    per_frame = [f for f in formats if f != "usd"]
    workers = local or os.cpu_count() or 1
    chunk = chunk or max(1, -(-len(numbers) // (2 * workers)))
    parts = [(numbers[i], numbers[min(i + chunk, len(numbers)) - 1]) for i in range(0, len(numbers), chunk)]
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.export.json").unlink(missing_ok=True)  # incomplete from now until the new one is written
    token = f"{os.getpid()}-{secrets.token_hex(4)}"
    stages = [str(out / f".{name}.part{n}.stage-{token}") for n in range(len(parts) + 1)]
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           dashboard_address=None) if scheduler is None else None
    try:
        with Client(cluster if cluster is not None else scheduler) as client:
            futures = [client.submit(_export_part, exe, frames_file, stages[n], name, a, b, per_frame, options,
                                     pure=False, retries=2) for n, (a, b) in enumerate(parts) if per_frame]
            if "usd" in formats:
                futures.append(client.submit(_export_part, exe, frames_file, stages[-1], name, numbers[0], None,
                                             ["usd"], options, pure=False, retries=2))
            order = {f.key: n for n, f in enumerate(futures)}
            manifests = [None] * len(futures)
            for done, future in enumerate(as_completed(futures), 1):
                manifests[order[future.key]] = future.result()
                log(f"export: {done}/{len(futures)} parts")
        # Every part's files into place, then the one manifest.
        merged = dict(manifests[0])
        merged["formats"] = list(formats)
        frames = {}
        for m in manifests:
            for entry in m["frames"]:
                known = frames.setdefault(entry["frame"], dict(entry, files=[]))
                known["files"] += [f for f in entry["files"] if f not in known["files"]]
        merged["frames"] = [frames[k] for k in sorted(frames)]
        merged["files"] = sorted({f for m in manifests for f in m.get("files", [])})
        for stage in stages:
            if not Path(stage).exists():
                continue
            for f in Path(stage).iterdir():
                if f.name != f"{name}.export.json":
                    f.replace(out / f.name)
        staged = out / f".{name}.export.json.{token}"
        staged.write_text(json.dumps(merged, indent=1))
        staged.replace(out / f"{name}.export.json")
        return merged
    finally:
        if cluster is not None:
            cluster.close()
        for stage in stages:
            shutil.rmtree(stage, ignore_errors=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="flowclip-batch", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run a job spec's tasks on a Dask cluster")
    run.add_argument("spec")
    where = run.add_mutually_exclusive_group()
    where.add_argument("--local", type=int, default=None, help="a LocalCluster of N worker processes (default)")
    where.add_argument("--scheduler", help="a running scheduler's address, tcp://HOST:8786")
    where.add_argument("--cluster", help="a cluster config (YAML/JSON): jobs on Slurm, PBS, SGE, LSF... "
                                         "through dask-jobqueue (docs/batch.md)")
    run.add_argument("--binary", help="the flowclip executable (default: $FLOWCLIP_BIN or flowclip on PATH)")
    run.add_argument("--dry-run", action="store_true", help="check the spec and list its tasks; run nothing")
    run.add_argument("--progress", choices=["text", "json"], default="text",
                     help="json: one JSON object per line on stdout (plan, task, done, end, error) for a program "
                          "that follows the batch (the server's jobs); text lines go to stderr")
    run.add_argument("--watch-stdin", action="store_true",
                     help="stop the batch and everything it started when stdin closes (the program that started "
                          "it, e.g. the server, has died)")
    exp = sub.add_parser("export", help="surfaces of a particle export, frame ranges across a Dask cluster")
    exp.add_argument("frames", help="a particle export (.h5) of `flowclip run --export` or a session")
    exp.add_argument("--out", required=True)
    exp.add_argument("--formats", default="vdb,ply")
    exp.add_argument("--name")
    exp.add_argument("--surface", action="append", default=[], help="KEY=VALUE, as flowclip export")
    exp.add_argument("--format-setting", action="append", default=[], help="FORMAT.KEY=VALUE, as flowclip export")
    exp.add_argument("--chunk", type=int, help="frames per task (default: a fair share, two per worker)")
    where = exp.add_mutually_exclusive_group()
    where.add_argument("--local", type=int, default=None, help="a LocalCluster of N worker processes (default)")
    where.add_argument("--scheduler", help="a running scheduler's address, tcp://HOST:8786")
    exp.add_argument("--binary", help="the flowclip executable (default: $FLOWCLIP_BIN or flowclip on PATH)")
    from . import commands  # the generic runner of independent commands (commands.py)

    commands.add_parser(sub)
    a = ap.parse_args(argv)
    import logging

    logging.getLogger("distributed").setLevel(logging.WARNING)  # the progress lines are ours
    if a.command == "commands":
        return commands.main(a)
    if a.command == "export":
        try:
            m = export_frames(a.frames, a.out, [f for f in a.formats.split(",") if f], name=a.name,
                              surface=a.surface, format_settings=a.format_setting, chunk=a.chunk,
                              local=a.local, scheduler=a.scheduler, binary=a.binary)
        except (SpecError, RuntimeError, OSError) as e:
            print(f"flowclip-batch: {e}", file=sys.stderr)
            return 2
        print(f"flowclip-batch: {len(m['frames'])} frames exported into {a.out}")
        return 0
    as_json = a.progress == "json"
    emitting = threading.Lock()

    def emit(e):
        if as_json:  # one write per line: events come from the client's event loop and from this thread
            with emitting:
                sys.stdout.write(json.dumps(e) + "\n")
                sys.stdout.flush()

    if a.watch_stdin:
        def watch():
            while os.read(0, 65536):  # the raw descriptor: a buffered stdin would stop the interpreter's exit
                pass
            os.killpg(os.getpgrp(), signal.SIGKILL)  # its workers and their flowclip runs too

        threading.Thread(target=watch, daemon=True).start()

    try:
        spec = load_spec(a.spec)
        if a.dry_run:
            for t in plan(spec, a.binary):
                print(f"{t.id} {json.dumps(t.overrides)} -> {t.folder}")
            return 0
        config = load_cluster_config(a.cluster) if a.cluster else None
        if config is not None:
            check_cluster(config, spec.get("threads", 1))  # checked before anything is submitted
        log = (lambda line: print(line, file=sys.stderr, flush=True)) if as_json else print
        results = run_batch(spec, local=a.local or os.cpu_count(), scheduler=a.scheduler, cluster_config=config,
                            binary=a.binary, log=log, event=emit)
    except SpecError as e:
        emit({"event": "error", "message": str(e)})
        print(f"flowclip-batch: {e}", file=sys.stderr)
        return 2
    except Exception as e:  # a task that failed on every attempt
        lines = [line for line in str(e).strip().splitlines() if line.strip()]
        # Which task and how it ended (the first line), and the cause (the last).
        message = " ... ".join(dict.fromkeys([lines[0], lines[-1]])) if lines else type(e).__name__
        emit({"event": "error", "message": message[:2000]})
        raise
    ran = sum(not r["skipped"] for r in results)
    emit({"event": "end", "tasks": len(results), "ran": ran})
    out = sys.stderr if as_json else sys.stdout
    print(summary_table(results), file=out)
    print(f"flowclip-batch: {len(results)} tasks, {ran} run, {len(results) - ran} already complete", file=out)
    return 0


if __name__ == "__main__":
    # As flowclip.batch, not __main__: the tasks' functions then go to the workers by name.
    from flowclip.batch import main as _main

    sys.exit(_main())
