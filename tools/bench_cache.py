#!/usr/bin/env python3
"""Edit-and-see benchmark of `flowclip serve`: how soon a live viewer sees the first frame an edit
changes, how long the session takes to re-simulate the frames the edit made stale, and what the
checkpoints behind that cost in memory and time.

For each scene (drop2d, 2D, and a 3D tank with an instance of a template recorded here from a
coarse 3D dam break) three identical sessions are simulated for --seconds, paused, each with a
live stream subscribed: the default (a checkpoint every K frames, --checkpoint-every, default 10,
and dense: every frame in between too, memory allowing), sparse (every K frames only,
checkpoint_dense=false) and none (checkpoint_every=0: every edit re-simulates from frame 0).
Then, for an edit at the start, the middle and the end of that stretch (t = 0, seconds/2,
seconds - 0.05), the instance's transform track is changed from time t on, on each session in
turn, and each is
put back to the original scene (the same edit undone) before the next edit, so that the edits are
comparable. Each edit measures:

  first updated frame  wall time from sending the PATCH to the first stream Frame whose number is
                       at least the edit answer's `frame` (the first frame the edit changes)
  done                 wall time from sending the PATCH to the first stream state with nothing
                       stale and no re-simulation under way (then the session is checked idle)
  re-simulated frames  the state's cache.simulating {from, to}: frames to - from were simulated

and the checkpoints' stored and raw bytes per fluid particle, save and restore ms as the server
reports them. Targets (checked against the session's mean frame compute time, stats wall_ms):

  first frame   the first updated frame reaches the viewer within one frame's compute time
                + 100 ms (the default checkpoints)
  late edit     the edit at the end re-simulates at most K frames plus the frames from its first
                changed frame on (in frames; and in time, at the mean frame time + 100 ms)

Writes OUT/cache.md and OUT/cache.json (machine, date, command, every figure, the targets and
whether each is met). Usage: tools/bench_cache.py [--out bench/cache] [--quick] [--repeat N]
(`make bench-cache`; --quick is a short smoke run: 0.5 s per scene, a coarser 3D scene, one
repetition). Not part of `make test` except through its smoke test, tests/test_bench_cache.py.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from bench_report import loadavg, machine  # tools/, beside this script
from flowclip import FlowClipServer  # clients/python, installed into build/venv by make setup

ROOT = Path(__file__).resolve().parent.parent
FLOWCLIP_BIN = Path(os.environ.get("FLOWCLIP_BIN", ROOT / "build" / "flowclip"))

FRAME_RATE = 60
FIRST_FRAME_ALLOWANCE_MS = 100.0  # the targets' allowance beyond one frame's compute time
WAIT_S = 900.0                    # generous: a loaded machine is slow, never a hang


def log(msg: str):
    print(msg, flush=True)


def summary(values) -> dict:
    values = [float(v) for v in values if v is not None]
    if not values:
        return {"median": None, "min": None, "max": None, "samples": []}
    return {"median": statistics.median(values), "min": min(values), "max": max(values),
            "samples": [round(v, 3) for v in values]}


# ------------------------------------------------------------------ stream ---

class Viewer:
    """A live viewer: the session's stream, read by a thread that timestamps every message."""

    def __init__(self, server, sid):
        self.stream = server.stream(sid)
        self.stream.subscribe(max_frame_rate=0.0)
        self.messages: list[tuple[float, dict]] = []
        self.cv = threading.Condition()
        self.stop = threading.Event()
        self.error = None
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self):
        while not self.stop.is_set():
            try:
                m = self.stream.recv(timeout=0.2)
            except TimeoutError:
                continue
            except Exception as e:  # the connection closed
                self.error = e
                break
            t = time.monotonic()
            if m["type"] == "frame":  # keep what the benchmark reads, not the positions
                m = {"type": "frame", "frame": m["frame"], "wall_ms": m["stats"].get("wall_ms")}
            with self.cv:
                self.messages.append((t, m))
                self.cv.notify_all()

    def mark(self) -> int:
        with self.cv:
            return len(self.messages)

    def wait_for(self, start: int, where, timeout=WAIT_S, what="a message"):
        """(index, time, message) of the first message from index `start` on satisfying `where`."""
        deadline = time.monotonic() + timeout
        i = start
        with self.cv:
            while True:
                while i < len(self.messages):
                    t, m = self.messages[i]
                    if where(m):
                        return i, t, m
                    i += 1
                left = deadline - time.monotonic()
                if left <= 0 or self.error is not None:
                    raise TimeoutError(f"no {what} on the stream within {timeout:.0f} s ({self.error})")
                self.cv.wait(min(left, 0.5))

    def between(self, start: int, end: int):
        with self.cv:
            return list(self.messages[start:end])

    def close(self):
        self.stop.set()
        self.thread.join(5)
        self.stream.close()


def cache_stale(m) -> bool:
    c = (m.get("state") or {}).get("cache") or {}
    return m["type"] == "state" and bool(c.get("stale"))


def cache_done(m) -> bool:
    c = (m.get("state") or {}).get("cache") or {}
    return m["type"] == "state" and "stale" in c and not c["stale"] and c.get("simulating") is None


def settled(api, sid, timeout=WAIT_S):
    """The state once nothing is stale or being re-simulated and the session is idle."""
    deadline = time.monotonic() + timeout
    while api.session(sid)["cache"]["stale"]:
        if time.monotonic() > deadline:
            raise TimeoutError(f"session {sid} still has stale frames")
        time.sleep(0.05)
    return api.wait_paused(sid, timeout=timeout)


# ------------------------------------------------------------------ scenes ---

def moved_key(key: dict, dim: int, delta: float, time_s=None) -> dict:
    k = {**key, "translation": [key["translation"][0] + delta] + list(key["translation"][1:dim])}
    if time_s is not None:
        k["time"] = time_s
    return k


def frame_of(time_s: float) -> int:
    """The first frame whose simulation reads scene time `time_s` or later (frame n covers
    (t(n-1), t(n)]): the first changed frame an edit from `time_s` on should be answered with."""
    duration = 1.0 / FRAME_RATE
    n = max(1, math.floor(time_s / duration) + 1)
    while n > 1 and (n - 1) * duration > time_s:  # the simulation's own frame ends
        n -= 1
    while n * duration <= time_s:
        n += 1
    return n


def edit_keys(k0: dict, t: float, dim: int, delta: float) -> list:
    """The instance's track changed from time t on: at t = 0 k0 moved; else k0, k0 again at t,
    then k0 moved a little at t + 0.05."""
    if t <= 0:
        return [moved_key(k0, dim, delta)]
    return [k0, {**k0, "time": t}, moved_key(k0, dim, delta, t + 0.05)]


def drop2d_scene(api) -> dict:
    """scenes/drop2d.json with the instance's transform track written out (its first key; the
    identity when the file has none), so that the edits replace one key track by another."""
    scene = api.scene("drop2d")
    inst = scene["instances"][0]
    if not inst.get("transform"):
        inst["transform"] = [{"time": 0.0, "translation": [0.0, 0.0]}]
    else:
        inst["transform"] = inst["transform"][:1]
    return scene


def dambreak3d_coarse(api, radius: float) -> dict:
    scene = api.scene("dambreak3d")
    return {**scene, "name": "dambreak3d_coarse", "particle_radius": radius}


def pool3d_scene(recording: dict, template: str, speed: float) -> dict:
    """The dam break's tank with a shallow pool and an instance of the recorded column template."""
    lo, hi = recording["domain"]["min"], recording["domain"]["max"]
    depth = 0.1
    return {**recording, "name": "pool3d", "duration": 2,
            "fluid_blocks": [{"min": list(lo), "max": [hi[0], lo[1] + depth, hi[2]], "phase": "water"}],
            "instances": [{"name": "column", "template": template, "start": 0.0, "speed": speed,
                           "transform": [{"time": 0.0, "translation": [0.5, depth, 0.0]}]}]}


# ------------------------------------------------------------------ session ---

class Bench:
    def __init__(self, server, api, threads):
        self.server, self.api, self.threads = server, api, threads

    def start(self, scene, every, frames, label, dense=True):
        api = self.api
        sid = api.create_session(scene, threads=self.threads, checkpoint_every=every, checkpoint_dense=dense)["id"]
        viewer = Viewer(self.server, sid)
        t0 = time.monotonic()
        api.step(sid, frames)
        st = settled(api, sid)
        elapsed = time.monotonic() - t0
        if st["status"] != "paused" or st["frame"] != frames:
            raise RuntimeError(f"{label}: session {st['status']} at frame {st['frame']} (wanted {frames})")
        if not st["shown"]["live"]:
            raise RuntimeError(f"{label}: the session's viewer is not live")
        stats = [f for f in api.stats(sid) if 1 <= f["frame"] <= frames]
        walls = [f["wall_ms"] for f in stats if f.get("wall_ms")]
        log(f"  {label}: {frames} frames in {elapsed:.1f} s, {statistics.mean(walls):.1f} ms a frame "
            f"(stats wall_ms), {st['particles']['liquid'] + st['particles']['temporary']} fluid particles, "
            f"checkpoints {st['cache']['checkpoints']}")
        # Beyond the step itself (checkpoint saves, snapshots, streaming), per frame.
        outside_ms = (elapsed * 1e3 - sum(walls)) / frames
        return {"sid": sid, "viewer": viewer, "state": st, "stats": stats, "simulate_s": elapsed,
                "mean_frame_ms": statistics.mean(walls), "median_frame_ms": statistics.median(walls),
                "outside_step_ms": outside_ms}

    def edit(self, sess, name, keys):
        """One timed edit of the instance's track; returns its figures once re-simulation is done."""
        api, viewer, sid = self.api, sess["viewer"], sess["sid"]
        mark = viewer.mark()
        t0 = time.monotonic()
        answer = api.update_instance(sid, name, {"transform": keys})
        t_answer = time.monotonic()
        polled = api.session(sid)["cache"]
        edit = answer["edit"]
        if not edit.get("accepted"):
            raise RuntimeError(f"edit refused: {edit}")
        first = edit["frame"]
        i_first, t_first, _ = viewer.wait_for(
            mark, lambda m: m["type"] == "frame" and m["frame"] >= first, what=f"frame >= {first}")
        # Frames and states travel separately: the final state may come before the last frames.
        # The edit's own state (stale frames) first, then the first one with none.
        i_stale, _, _ = viewer.wait_for(mark, cache_stale, what="state with stale frames")
        i_done, t_done, done_msg = viewer.wait_for(i_stale, cache_done, what="state with the cache valid")
        i_done = max(i_done, i_first)
        st = settled(api, sid)
        seen = viewer.between(mark, i_done + 1)
        running = [m["state"]["cache"]["simulating"] for _, m in seen
                   if m["type"] == "state" and ((m.get("state") or {}).get("cache") or {}).get("simulating")]
        if polled.get("simulating"):
            running.append(polled["simulating"])
        resim_from = min((r["from"] for r in running), default=None)
        resim_to = max((r["to"] for r in running), default=None)
        updated = sorted({m["frame"] for _, m in seen if m["type"] == "frame" and m["frame"] >= first})
        stats = {f["frame"]: f for f in api.stats(sid)}
        resim_walls = ([stats[n]["wall_ms"] for n in range(resim_from + 1, resim_to + 1)
                        if n in stats and stats[n].get("wall_ms")] if resim_from is not None else [])
        cache = st["cache"]
        return {
            "edit_frame": first,
            "answer_ms": (t_answer - t0) * 1e3,
            "first_updated_frame_ms": (t_first - t0) * 1e3,
            "done_ms": (t_done - t0) * 1e3,
            "from": resim_from, "to": resim_to,
            "frames_simulated": (resim_to - resim_from) if resim_from is not None else None,
            "frames_before_first_updated": (first - resim_from) if resim_from is not None else None,
            "updated_frames_streamed": len(updated),
            "resim_mean_frame_ms": statistics.mean(resim_walls) if resim_walls else None,
            "restore_ms": cache.get("checkpoint_restore_ms"),
            "save_ms": cache.get("checkpoint_save_ms"),
            "final_frame": st["frame"], "valid": cache["valid"],
        }


def checkpoint_figures(sess, every, dense) -> dict:
    st = sess["state"]
    cache = st["cache"]
    by_frame = {f["frame"]: f for f in sess["stats"]}
    fluid = [by_frame[n].get("liquid_particles", 0) + by_frame[n].get("temporary_particles", 0)
             for n in cache["checkpoints"] if n in by_frame]
    count = len(cache["checkpoints"])
    mean_fluid = statistics.mean(fluid) if fluid else None
    per = (lambda b: b / count / mean_fluid) if count and mean_fluid else (lambda b: None)
    return {"every": every, "dense": dense, "count": count, "frames": cache["checkpoints"],
            "stored_bytes": cache["checkpoint_bytes"], "raw_bytes": cache.get("checkpoint_raw_bytes"),
            "memory_checkpoint_bytes": st["memory"].get("checkpoint_bytes"),
            "history_bytes": st["memory"]["history_bytes"],
            "cap_bytes": cache.get("checkpoint_cap"),
            "fluid_particles_mean": mean_fluid,
            "stored_bytes_per_particle": per(cache["checkpoint_bytes"]),
            "raw_bytes_per_particle": per(cache.get("checkpoint_raw_bytes") or 0),
            "compression_ratio": (cache["checkpoint_raw_bytes"] / cache["checkpoint_bytes"]
                                  if cache.get("checkpoint_bytes") else None)}


def run_scene(bench, key, scene, args, frames, extra=None) -> dict:
    api = bench.api
    dim = scene["dimension"]
    inst = scene["instances"][0]
    name = inst["name"]
    k0 = {"time": 0.0, **inst["transform"][0]}
    original = [k0]
    delta = args.delta
    K = args.checkpoint_every
    log(f"[{key}] {dim}D, {frames} frames, threads={args.threads}: three sessions "
        f"(checkpoint_every={K} dense, {K} sparse, and 0)")
    ck = bench.start(scene, K, frames, f"checkpoint_every={K}, dense")
    sparse = bench.start(scene, K, frames, f"checkpoint_every={K}, sparse", dense=False)
    nock = bench.start(scene, 0, frames, "checkpoint_every=0")
    sessions = (("checkpoints", ck), ("sparse", sparse), ("no_checkpoints", nock))
    mode_label = {"checkpoints": f"K={K}+dense", "sparse": f"K={K}", "no_checkpoints": "K=0"}
    seconds = frames / FRAME_RATE
    edit_times = [("start", 0.0), ("middle", round(seconds / 2, 4)), ("end", round(seconds - 0.05, 4))]
    results = {label: {"time": t, **{mode: [] for mode, _ in sessions}} for label, t in edit_times}
    restore_ms = {"checkpoints": [], "sparse": []}
    save_ms = {mode: [sess["state"]["cache"]["checkpoint_save_ms"]] for mode, sess in sessions[:2]}
    for rep in range(args.repeat):
        for label, t in edit_times:
            keys = edit_keys(k0, t, dim, delta)
            for mode, sess in sessions:
                r = bench.edit(sess, name, keys)
                results[label][mode].append(r)
                if mode in restore_ms:
                    if r["from"]:
                        restore_ms[mode].append(r["restore_ms"])
                    save_ms[mode].append(r["save_ms"])
                log(f"  edit at {t:.2f} s ({label}, frame {r['edit_frame']}), {mode_label[mode]}, "
                    f"rep {rep + 1}/{args.repeat}: first updated frame {r['first_updated_frame_ms']:.0f} ms, "
                    f"done {r['done_ms'] / 1e3:.2f} s, re-simulated {r['from']}..{r['to']} "
                    f"({r['frames_simulated']} frames)  [load {loadavg()}]")
                back = bench.edit(sess, name, original)  # undo: the original scene again
                if mode in restore_ms and back["from"]:
                    restore_ms[mode].append(back["restore_ms"])
                if back["final_frame"] != frames:
                    raise RuntimeError(f"session at frame {back['final_frame']} after the undo")
    mean_ms = ck["mean_frame_ms"]
    edits = []
    for label, t in edit_times:
        rc = results[label]["checkpoints"]
        first_frame = rc[0]["edit_frame"]
        fields = ("first_updated_frame_ms", "done_ms", "answer_ms", "resim_mean_frame_ms")
        expected = frame_of(max(t, inst.get("start", 0.0)))
        e = {"label": label, "time": t, "edit_frame": first_frame, "expected_frame": expected,
             "answered_earlier_than_expected": first_frame < expected,
             "keys": edit_keys(k0, t, dim, delta)}
        for mode, _ in sessions:
            rs = results[label][mode]
            e[mode] = {f: summary(r[f] for r in rs) for f in fields}
            e[mode].update({f: rs[0][f] for f in ("from", "to", "frames_simulated", "frames_before_first_updated")})
            e[mode]["updated_frames_streamed"] = summary(r["updated_frames_streamed"] for r in rs)
            if any(r["from"] != rs[0]["from"] or r["edit_frame"] != first_frame for r in rs):
                e[mode]["varied"] = [(r["edit_frame"], r["from"], r["to"]) for r in rs]
        lat = e["checkpoints"]["first_updated_frame_ms"]["median"]
        target_ms = mean_ms + FIRST_FRAME_ALLOWANCE_MS
        e["first_frame_target"] = {
            "target_ms": target_ms, "measured_ms": lat, "met": lat <= target_ms,
            # what the latency would be if only the frames up to the first changed one cost time
            "frames_to_simulate": e["checkpoints"]["frames_before_first_updated"],
            "beyond_those_frames_ms": (lat - e["checkpoints"]["frames_before_first_updated"] * mean_ms
                                       if e["checkpoints"]["frames_before_first_updated"] is not None else None)}
        d0, dk = e["no_checkpoints"]["done_ms"]["median"], e["checkpoints"]["done_ms"]["median"]
        e["speedup_done"] = d0 / dk if dk else None
        edits.append(e)
    late = edits[-1]
    after = late["checkpoints"]["to"] - late["edit_frame"] + 1
    budget_frames = K + after
    budget_ms = budget_frames * mean_ms + FIRST_FRAME_ALLOWANCE_MS
    late_target = {
        "edit_frame": late["edit_frame"], "frames_after": after, "k": K,
        "budget_frames": budget_frames, "frames_simulated": late["checkpoints"]["frames_simulated"],
        "frames_met": late["checkpoints"]["frames_simulated"] <= budget_frames,
        "frames_simulated_without_checkpoints": late["no_checkpoints"]["frames_simulated"],
        "budget_ms": budget_ms, "done_ms": late["checkpoints"]["done_ms"]["median"],
        "time_met": late["checkpoints"]["done_ms"]["median"] <= budget_ms,
        "done_ms_without_checkpoints": late["no_checkpoints"]["done_ms"]["median"]}
    late_target["met"] = late_target["frames_met"] and late_target["time_met"]
    out = {
        "scene": {"name": scene["name"], "dimension": dim, "particle_radius": scene["particle_radius"],
                  "instance": name, "template": inst["template"],
                  "particles": ck["state"]["particles"], "frames": frames},
        "initial": {mode: {"simulate_s": s["simulate_s"], "mean_frame_ms": s["mean_frame_ms"],
                           "median_frame_ms": s["median_frame_ms"], "outside_step_ms": s["outside_step_ms"]}
                    for mode, s in sessions},
        "mean_frame_ms": mean_ms,
        "checkpoints": {**checkpoint_figures(ck, K, True), "save_ms": summary(save_ms["checkpoints"]),
                        "restore_ms": summary(restore_ms["checkpoints"])},
        "sparse_checkpoints": {**checkpoint_figures(sparse, K, False), "save_ms": summary(save_ms["sparse"]),
                               "restore_ms": summary(restore_ms["sparse"])},
        "edits": edits,
        "edits_answered_earlier_than_expected": [e["label"] for e in edits if e["answered_earlier_than_expected"]],
        "targets": {"first_frame": {"met": all(e["first_frame_target"]["met"] for e in edits),
                                    "per_edit": {e["label"]: e["first_frame_target"]["met"] for e in edits}},
                    "late_edit": late_target},
    }
    if extra:
        out.update(extra)
    for _, sess in sessions:
        sess["viewer"].close()
        api.delete_session(sess["sid"])
    return out


def record_template_3d(api, args, frames) -> tuple[dict, dict]:
    """A coarse 3D dam break, and a template of its collapsing column recorded from its history."""
    recording = dambreak3d_coarse(api, args.radius_3d)
    first = 5
    count = math.ceil(frames * args.speed_3d) + 2    # covers `frames` frames at the instance's speed
    last = first + count - 1
    log(f"[3d] recording a template: dam break at particle_radius {args.radius_3d}, frames {first}..{last}")
    sid = api.create_session(recording, threads=args.threads, checkpoint_every=0)["id"]
    t0 = time.monotonic()
    api.step(sid, last)
    st = settled(api, sid)
    simulate_s = time.monotonic() - t0
    lo = recording["domain"]["min"]
    region_min, region_max = list(lo), [1.5, 1.1, recording["domain"]["max"][2]]
    t0 = time.monotonic()
    tpl = api.record_template(sid, "bench_column3d", region_min, region_max, first, last, force=True)
    record_s = time.monotonic() - t0
    api.delete_session(sid)
    log(f"  {st['particles']['liquid']} liquid particles, {last} frames in {simulate_s:.1f} s; template "
        f"{tpl['frames']} frames, {tpl['avg_particles']:.0f} particles on average, {record_s:.2f} s to record")
    info = {"recording_scene": {"name": recording["name"], "based_on": "scenes/dambreak3d.json",
                                "particle_radius": args.radius_3d, "particles": st["particles"],
                                "frames": last, "simulate_s": simulate_s},
            "template": {"name": tpl["name"], "frames": tpl["frames"], "first_frame": first, "last_frame": last,
                         "region_min": region_min, "region_max": region_max,
                         "avg_particles": tpl["avg_particles"], "bytes": tpl["bytes"], "record_s": record_s,
                         "instance_speed": args.speed_3d}}
    return recording, info


# ------------------------------------------------------------------ report ---

def fmt(v, digits=0, unit=""):
    if v is None:
        return "–"
    if isinstance(v, float) and not math.isfinite(v):
        return "–"
    return f"{v:,.{digits}f}{unit}"


def rng(s, digits=0, scale=1.0):
    if s["median"] is None:
        return "–"
    if len(s["samples"]) <= 1:
        return fmt(s["median"] * scale, digits)
    return f"{fmt(s['median'] * scale, digits)} ({fmt(s['min'] * scale, digits)}–{fmt(s['max'] * scale, digits)})"


def yes(b):
    return "**met**" if b else "**not met**"


def markdown(report) -> str:
    s = report["settings"]
    K = s["checkpoint_every"]
    lines = [
        "# Edit and see: the cost of an edit (checkpoints and re-simulation)",
        "",
        f"Measured {report['date']} on {report['machine']['cpu']} ({report['machine']['cores']} cores; "
        f"load average {report['machine']['loadavg_at_start']} at the start, {report['loadavg_at_end']} "
        f"at the end: the machine was shared; niceness {report['machine']['niceness']}), `flowclip serve` on loopback, "
        f"{s['threads']} threads per session.",
        "",
        "```sh",
        report["command"],
        "```",
        "",
        f"Each scene: {s['frames']} frames ({s['seconds']:g} s) simulated in three identical sessions, paused, "
        f"each with a live stream subscribed: the default (a checkpoint every {K} frames and, dense, every frame "
        f"in between as memory allows), sparse (every {K} frames only, `checkpoint_dense: false`) and none "
        f"(`checkpoint_every: 0`, every edit re-simulates from frame 0). Each edit changes the instance's "
        f"transform track from time t on (at t = 0 the first key moves {s['delta_m']} m along x; later, "
        f"the key is repeated at t and moved {s['delta_m']} m at t + 0.05 s) and is undone before the next "
        f"one, so that every edit starts from the same recorded frames. {s['repeat']} repetition(s) per "
        f"edit: the median, with the range when there are several.",
        "",
        "- **first updated frame**: from sending the PATCH to the first stream Frame numbered at least the "
        "edit answer's `frame` (the first frame the edit changes).",
        "- **done**: from sending the PATCH to the first stream state with nothing stale and no "
        "re-simulation under way.",
        "- **re-simulated**: the state's `cache.simulating` `from`..`to` (frames `to - from` simulated).",
        f"- **frame compute time**: the mean of the stats' `wall_ms` over the first run's frames.",
        "",
        "Targets:",
        "",
        f"- **first frame**: the first updated frame within one frame's compute time + "
        f"{FIRST_FRAME_ALLOWANCE_MS:.0f} ms (the default checkpoints).",
        f"- **late edit**: the edit at the end re-simulates at most K = {K} frames plus the frames from "
        f"its first changed frame on; in time, at most those frames at the mean frame compute time + "
        f"{FIRST_FRAME_ALLOWANCE_MS:.0f} ms.",
        "",
    ]
    verdict = []
    for key, sc in report["scenes"].items():
        t = sc["targets"]
        verdict.append(f"| {key} | {fmt(sc['mean_frame_ms'], 1)} ms | "
                       + ", ".join(f"{e['label']} {fmt(e['first_frame_target']['measured_ms'])} ms"
                                   for e in sc["edits"])
                       + f" (target {fmt(sc['edits'][0]['first_frame_target']['target_ms'])} ms): "
                       + yes(t["first_frame"]["met"])
                       + f" | {t['late_edit']['frames_simulated']} frames ≤ {t['late_edit']['budget_frames']}: "
                       + yes(t["late_edit"]["frames_met"])
                       + f"; {fmt(t['late_edit']['done_ms'])} ms ≤ {fmt(t['late_edit']['budget_ms'])} ms: "
                       + yes(t["late_edit"]["time_met"]) + " |")
    lines += ["## Verdict", "",
              "| scene | frame compute time | first updated frame (first frame target) | late edit |",
              "|---|---|---|---|", *verdict, ""]
    for key, sc in report["scenes"].items():
        scn = sc["scene"]
        p = scn["particles"]
        lines += [f"## {key}", ""]
        desc = (f"Scene `{scn['name']}` ({scn['dimension']}D, particle radius {scn['particle_radius']} m): "
                f"{p['liquid']} liquid + {p['temporary']} temporary particles at frame {scn['frames']} "
                f"({p['boundary']} boundary), instance `{scn['instance']}` of template `{scn['template']}`.")
        if "template" in sc:
            tp, rec = sc["template"], sc["recording_scene"]
            desc += (f" The template was recorded here: `{rec['based_on']}` at particle radius "
                     f"{rec['particle_radius']} m ({rec['particles']['liquid']} particles, {rec['frames']} frames "
                     f"in {fmt(rec['simulate_s'], 1)} s), frames {tp['first_frame']}..{tp['last_frame']} of the "
                     f"region {tp['region_min']}–{tp['region_max']} around the collapsing column "
                     f"({tp['frames']} frames, {fmt(tp['avg_particles'])} particles on average, "
                     f"{fmt(tp['bytes'] / 2**20, 1)} MB, recorded in {fmt(tp['record_s'], 2)} s); the scene is the "
                     f"same tank with a {0.1} m pool and the instance at speed {tp['instance_speed']} (so that it "
                     f"is active through the whole stretch).")
        lines += [desc, ""]
        ini = sc["initial"]
        lines += [f"First run: {fmt(ini['checkpoints']['simulate_s'], 1)} s for {scn['frames']} frames with "
                  f"dense checkpoints, {fmt(ini['sparse']['simulate_s'], 1)} s with sparse ones, "
                  f"{fmt(ini['no_checkpoints']['simulate_s'], 1)} s without; frame compute time "
                  f"{fmt(sc['mean_frame_ms'], 1)} ms (mean; median {fmt(ini['checkpoints']['median_frame_ms'], 1)} ms). "
                  f"Per frame beyond the step itself (checkpoint saves, the snapshot, streaming): "
                  f"{fmt(ini['checkpoints']['outside_step_ms'], 1)} ms dense, {fmt(ini['sparse']['outside_step_ms'], 1)} ms "
                  f"sparse, {fmt(ini['no_checkpoints']['outside_step_ms'], 1)} ms without.",
                  ""]
        lines += ["| edit at | first changed frame | K | re-simulated | first updated frame ms | done ms "
                  "| frames to simulate before it | beyond those at the mean frame time, ms | first frame target |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for e in sc["edits"]:
            for mode, kk in (("checkpoints", f"{K} + dense"), ("sparse", K), ("no_checkpoints", 0)):
                m = e[mode]
                tgt = ""
                beyond = ""
                if mode == "checkpoints":
                    ft = e["first_frame_target"]
                    tgt = f"≤ {fmt(ft['target_ms'])} ms: {yes(ft['met'])}"
                    beyond = fmt(ft["beyond_those_frames_ms"])
                lines.append(f"| {e['time']:g} s ({e['label']}) | {e['edit_frame']} | {kk} | "
                             f"{m['from']}..{m['to']} ({m['frames_simulated']} frames) | "
                             f"{rng(m['first_updated_frame_ms'])} | {rng(m['done_ms'])} | "
                             f"{m['frames_before_first_updated']} | {beyond} | {tgt} |")
        early = [e for e in sc["edits"] if e["answered_earlier_than_expected"]]
        for e in early:
            lines += ["", f"**Note:** the edit at {e['time']:g} s leaves the track unchanged before {e['time']:g} s "
                      f"(frame {e['expected_frame']} is the first that reads a later time), yet the server answered "
                      f"first changed frame {e['edit_frame']}: it re-simulated from frame {e['checkpoints']['from']} "
                      f"with checkpoints, more than the edit needs."]
        lines += ["", "Done without checkpoints ÷ done with them: "
                  + ", ".join(f"{e['label']} {fmt(e['speedup_done'], 1)}×" for e in sc["edits"]) + ".", ""]
        lt = sc["targets"]["late_edit"]
        lines += [f"Late edit (first changed frame {lt['edit_frame']}): {lt['frames_simulated']} frames "
                  f"re-simulated with checkpoints, {lt['frames_simulated_without_checkpoints']} without; the "
                  f"budget is K + {lt['frames_after']} = {lt['budget_frames']} frames: {yes(lt['frames_met'])}. "
                  f"In time: done in {fmt(lt['done_ms'])} ms (without checkpoints {fmt(lt['done_ms_without_checkpoints'])} ms) "
                  f"against {fmt(lt['budget_ms'])} ms: {yes(lt['time_met'])}.", ""]
        for ck in (sc["checkpoints"], sc["sparse_checkpoints"]):
            lines += checkpoint_table(ck)
    lines += [f"Whole run: {fmt(report['run_s'], 0)} s. Figures in [cache.json](cache.json).", ""]
    return "\n".join(lines)


def held(frames: list) -> str:
    """Frame numbers as ranges: [1, 2, 3, 10] -> "1–3, 10"."""
    out, i = [], 0
    while i < len(frames):
        j = i
        while j + 1 < len(frames) and frames[j + 1] == frames[j] + 1:
            j += 1
        out.append(str(frames[i]) if i == j else f"{frames[i]}–{frames[j]}")
        i = j + 1
    return ", ".join(out)


def checkpoint_table(ck) -> list:
    kind = f"every {ck['every']} frames" + (" and every frame in between (dense)" if ck["dense"] else " (sparse)")
    return ["| checkpoints, " + kind + " | |", "|---|---|",
                  f"| held | {ck['count']}: {held(ck['frames'])} |",
                  f"| stored (compressed) | {fmt(ck['stored_bytes'] / 2**20, 2)} MB, "
                  f"**{fmt(ck['stored_bytes_per_particle'], 1)} bytes per fluid particle** |",
                  f"| raw | {fmt(ck['raw_bytes'] / 2**20, 2)} MB, {fmt(ck['raw_bytes_per_particle'], 1)} bytes per "
                  f"fluid particle (compression {fmt(ck['compression_ratio'], 2)}×) |",
                  f"| fluid particles per checkpoint | {fmt(ck['fluid_particles_mean'])} (mean) |",
                  f"| beside the history | {fmt(ck['history_bytes'] / 2**20, 2)} MB of recorded frames; "
                  f"checkpoint cap {fmt((ck['cap_bytes'] or 0) / 2**20)} MB |",
                  f"| save ms of an every-K checkpoint (`checkpoint_save_ms`, archive + deflate) | {rng(ck['save_ms'], 2)} |",
                  f"| restore ms (`checkpoint_restore_ms`) | {rng(ck['restore_ms'], 2)} |",
                  ""]


# ------------------------------------------------------------------ main ---

def wait_for_binary(timeout=300.0):
    deadline = time.monotonic() + timeout
    while not (FLOWCLIP_BIN.exists() and os.access(FLOWCLIP_BIN, os.X_OK)):
        if time.monotonic() > deadline:
            raise SystemExit(f"{FLOWCLIP_BIN} is missing: build first (make build) or set FLOWCLIP_BIN")
        time.sleep(2)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="bench/cache", help="report directory (cache.md, cache.json)")
    ap.add_argument("--quick", action="store_true",
                    help="a short smoke run: 0.5 s per scene, a coarser 3D scene, one repetition")
    ap.add_argument("--seconds", type=float, help="simulated stretch per scene (default 1, quick 0.5)")
    ap.add_argument("--repeat", type=int, help="repetitions of each edit (default 3, quick 1)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--checkpoint-every", type=int, default=10)
    ap.add_argument("--radius-3d", type=float, help="3D particle radius (default 0.0125, quick 0.025)")
    ap.add_argument("--speed-3d", type=float, default=0.5, help="the 3D instance's playback speed")
    ap.add_argument("--delta", type=float, default=0.02, help="m the edit moves the instance")
    ap.add_argument("--scenes", default="2d,3d", help="which scenes: 2d, 3d or both")
    args = ap.parse_args(argv)
    args.seconds = args.seconds or (0.5 if args.quick else 1.0)
    args.repeat = args.repeat or (1 if args.quick else 3)
    args.radius_3d = args.radius_3d or (0.025 if args.quick else 0.0125)
    if args.checkpoint_every < 1:
        ap.error("--checkpoint-every must be at least 1 (the comparison run has none)")
    frames = round(args.seconds * FRAME_RATE)
    wanted = {s.strip() for s in args.scenes.split(",")}

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    def rel(path):
        path = os.path.abspath(path)
        return os.path.relpath(path, ROOT) if path.startswith(str(ROOT) + os.sep) else path
    command = " ".join(shlex.quote(a) for a in [rel(sys.executable), rel(sys.argv[0]),
                                                *(sys.argv[1:] if argv is None else argv)])
    report = {"machine": machine(), "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
              "command": command, "quick": args.quick, "binary": str(FLOWCLIP_BIN),
              "settings": {"seconds": args.seconds, "frames": frames, "threads": args.threads,
                           "checkpoint_every": args.checkpoint_every, "repeat": args.repeat,
                           "delta_m": args.delta, "frame_rate": FRAME_RATE,
                           "first_frame_allowance_ms": FIRST_FRAME_ALLOWANCE_MS},
              "scenes": {}}
    log(f"bench_cache: {report['machine']['cpu']}, {report['machine']['cores']} cores, "
        f"load {report['machine']['loadavg_at_start']}; {frames} frames per scene, {args.repeat} repetition(s)")
    wait_for_binary()
    t_run = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="flowclip-bench-cache-") as tmp:
        templates = Path(tmp) / "templates"
        templates.mkdir()
        src = ROOT / "templates" / "drop2d.h5"
        if src.exists():
            shutil.copy(src, templates / src.name)
        else:
            log("recording templates/recipes/drop2d.json (no templates/drop2d.h5)")
            subprocess.run([str(FLOWCLIP_BIN), "record", str(ROOT / "templates" / "recipes" / "drop2d.json"),
                            "--templates", str(templates), "--force", "--quiet"], check=True, timeout=600)
        with FlowClipServer(templates, ROOT / "scenes", Path(tmp) / "exports", binary=FLOWCLIP_BIN) as server:
            api = server.client()
            api.timeout = 120
            bench = Bench(server, api, args.threads)
            if "2d" in wanted:
                report["scenes"]["drop2d"] = run_scene(bench, "drop2d", drop2d_scene(api), args, frames)
            if "3d" in wanted:
                recording, info = record_template_3d(api, args, frames)
                scene = pool3d_scene(recording, info["template"]["name"], args.speed_3d)
                report["scenes"]["pool3d"] = run_scene(bench, "pool3d", scene, args, frames, extra=info)
    report["run_s"] = time.monotonic() - t_run
    report["loadavg_at_end"] = loadavg()
    report["targets_met"] = all(sc["targets"]["first_frame"]["met"] and sc["targets"]["late_edit"]["met"]
                                for sc in report["scenes"].values())
    (out / "cache.json").write_text(json.dumps(report, indent=1) + "\n")
    (out / "cache.md").write_text(markdown(report))
    log(f"done in {report['run_s']:.0f} s: {out / 'cache.md'}, {out / 'cache.json'}")
    for key, sc in report["scenes"].items():
        t = sc["targets"]
        log(f"  {key}: first frame target {'met' if t['first_frame']['met'] else 'NOT met'} "
            f"({', '.join(fmt(e['first_frame_target']['measured_ms']) + ' ms' for e in sc['edits'])} vs "
            f"{fmt(sc['edits'][0]['first_frame_target']['target_ms'])} ms); late edit "
            f"{'met' if t['late_edit']['met'] else 'NOT met'} ({t['late_edit']['frames_simulated']} frames vs "
            f"{t['late_edit']['budget_frames']}, {fmt(t['late_edit']['done_ms'])} ms vs "
            f"{fmt(t['late_edit']['budget_ms'])} ms)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
