#!/usr/bin/env python3
"""Soak benchmark of `flowclip serve`: S sessions × C clients for a set time, some clients well
behaved, some that stall (never read) and some that vanish (drop the connection mid-stream), with
REST edits and polls throughout. Samples the server's RSS, descriptors and health latency, and
writes a report (markdown + JSON: machine, date, command, figures) with a verdict:

  flat RSS     once every session's history has filled its cap, RSS over the second half of the
               rest of the run grows by less than --rss-growth-pct
  no error     no session in its error state, no unexpected error message, no 5xx answer
  no stall     every well-behaved reader got a frame at least every --stall-s seconds
  bounded fds  descriptors at the end within a margin of those at the start of the load

Usage: tools/soak.py [--seconds 600] [--sessions 8] [--clients 8] [--out bench/soak]
(`make bench-soak`). Not part of `make test`: it is a benchmark.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import random
import socket
import statistics
import sys
import threading
import time
from pathlib import Path

from bench_report import machine  # tools/, beside this script
from flowclip import FlowClipServer  # clients/python, installed into build/venv by make setup

ROOT = Path(__file__).resolve().parent.parent
FLOWCLIP_BIN = Path(os.environ.get("FLOWCLIP_BIN", ROOT / "build" / "flowclip"))


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def fds(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def scene(k: int) -> dict:
    """Alternating small 2D tanks: a resting block, and a falling one with a drop instance."""
    side = 0.4
    s = {"name": f"soak{k}", "dimension": 2, "particle_radius": 0.01,
         "domain": {"min": [0, 0], "max": [1, 1]},
         "fluid_blocks": [{"min": [0, 0], "max": [side, side]}]}
    if k % 2:
        s["fluid_blocks"] = [{"min": [0.3, 0.2], "max": [0.3 + side, 0.2 + side]}]
        s["instances"] = [{"name": "drop", "template": "drop2d", "start": 0.5}]
    return s


class Stats:
    def __init__(self):
        self.lock = threading.Lock()
        self.errors: list[str] = []
        self.frames = 0
        self.max_gap_s = 0.0
        self.rest_calls = 0
        self.rest_5xx = 0
        self.stalled_connections = 0
        self.vanished_connections = 0

    def error(self, text: str):
        with self.lock:
            if len(self.errors) < 50:
                self.errors.append(text)


def good_reader(server, sid, stop, stats):
    """Reads everything; records the longest wait between two frames."""
    try:
        with server.stream(sid, timeout=30) as stream:
            last = time.monotonic()
            while not stop.is_set():
                m = stream.recv(timeout=30)
                now = time.monotonic()
                if m["type"] == "frame":
                    with stats.lock:
                        stats.frames += 1
                        stats.max_gap_s = max(stats.max_gap_s, now - last)
                    last = now
                elif m["type"] == "error":
                    stats.error(f"{sid}: stream error {m['code']}: {m['message']}")
    except Exception as e:  # noqa: BLE001  (any failure of a good reader is a finding)
        if not stop.is_set():
            stats.error(f"{sid}: good reader: {e!r}")


def raw_upgrade(server, sid) -> socket.socket:
    host = server.url.removeprefix("http://")
    h, p = host.split(":")
    s = socket.create_connection((h, int(p)), timeout=30)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    s.sendall((f"GET /api/sessions/{sid}/stream HTTP/1.1\r\nHost: {host}\r\nUpgrade: websocket\r\n"
               "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
               "Sec-WebSocket-Version: 13\r\n\r\n").encode())
    return s


def staller(server, sid, stop, stats, rng):
    """Upgrades and never reads for 20-60 s (the server cuts it once its buffers fill), then
    closes and comes back."""
    while not stop.is_set():
        try:
            s = raw_upgrade(server, sid)
        except OSError as e:
            stats.error(f"{sid}: staller: {e!r}")
            return
        with stats.lock:
            stats.stalled_connections += 1
        stop.wait(rng.uniform(20, 60))
        s.close()


def vanisher(server, sid, stop, stats, rng):
    """Connects, reads a little, then drops the TCP connection without a close handshake."""
    while not stop.is_set():
        try:
            s = raw_upgrade(server, sid)
            s.recv(2048)
            time.sleep(rng.uniform(0.1, 2.0))
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")  # RST
            s.close()
            with stats.lock:
                stats.vanished_connections += 1
        except OSError as e:
            if not stop.is_set():
                stats.error(f"{sid}: vanisher: {e!r}")
        time.sleep(rng.uniform(0.1, 1.0))


def rest_client(server, sid, has_instance, stop, stats, rng):
    """Polls the session and edits its instance (or settings) at a human pace."""
    api = server.client()
    while not stop.is_set():
        try:
            if has_instance and rng.random() < 0.5:
                r = api.request("PATCH", "/api/sessions/{id}/instances/{name}", id=sid, name="drop",
                                json_body={"speed": rng.choice([0.5, 1.0, 1.5])})
            else:
                r = api.request("GET", "/api/sessions/{id}", id=sid)
            with stats.lock:
                stats.rest_calls += 1
                stats.rest_5xx += r.status_code >= 500
            if r.status_code >= 400 and r.status_code != 503:
                stats.error(f"{sid}: REST {r.status_code}: {r.text[:200]}")
            elif r.status_code == 200 and r.json().get("status") == "error":
                stats.error(f"{sid}: session in error: {r.json().get('error')}")
        except Exception as e:  # noqa: BLE001
            if not stop.is_set():
                stats.error(f"{sid}: REST client: {e!r}")
        time.sleep(rng.uniform(0.2, 1.0))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=600)
    ap.add_argument("--sessions", type=int, default=8)
    ap.add_argument("--clients", type=int, default=8, help="per session: 1 REST, 1 staller, 1 vanisher, the rest readers")
    ap.add_argument("--history-cap-mb", type=float, default=32)
    ap.add_argument("--fps", type=float, default=30, help="playback speed of every session")
    ap.add_argument("--sample-s", type=float, default=2.0)
    ap.add_argument("--stall-s", type=float, default=10.0, help="longest acceptable wait between frames of a reader")
    ap.add_argument("--rss-growth-pct", type=float, default=5.0)
    ap.add_argument("--out", default=str(ROOT / "bench" / "soak"))
    ap.add_argument("--templates", default=str(ROOT / "templates"))
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    rng = random.Random(args.seed)
    command = " ".join([Path(sys.argv[0]).as_posix()] + sys.argv[1:])
    stats, stop = Stats(), threading.Event()
    samples = []
    with FlowClipServer(args.templates, ROOT / "scenes", binary=FLOWCLIP_BIN,
                        history_cap_mb=args.history_cap_mb, max_sessions=args.sessions) as server:
        api = server.client()
        pid = server.proc.pid
        fds_idle = fds(pid)
        threads = []
        sids = []
        for k in range(args.sessions):
            st = api.create_session(scene(k), playback_speed=args.fps, threads=1)
            sids.append((st["id"], k % 2 == 1))
        for sid, has_instance in sids:
            readers = max(0, args.clients - 3)
            for _ in range(readers):
                threads.append(threading.Thread(target=good_reader, args=(server, sid, stop, stats), daemon=True))
            threads.append(threading.Thread(target=staller, args=(server, sid, stop, stats, random.Random(rng.random())),
                                            daemon=True))
            threads.append(threading.Thread(target=vanisher, args=(server, sid, stop, stats,
                                                                   random.Random(rng.random())), daemon=True))
            threads.append(threading.Thread(target=rest_client, args=(server, sid, has_instance, stop, stats,
                                                                      random.Random(rng.random())), daemon=True))
        for t in threads:
            t.start()
        for sid, _ in sids:
            api.play(sid, until=10**6)
        t0 = time.monotonic()
        next_report = 0.0
        while (elapsed := time.monotonic() - t0) < args.seconds:
            h0 = time.monotonic()
            try:
                health = api.health()
                health_ms = (time.monotonic() - h0) * 1000
            except Exception as e:  # noqa: BLE001
                stats.error(f"health: {e!r}")
                health, health_ms = {}, float("nan")
            states = [api.session(sid) for sid, _ in sids]
            frames = [st["frame"] for st in states]
            samples.append({"t_s": round(elapsed, 2), "rss_mb": round(rss_mb(pid), 1), "fds": fds(pid),
                            "health_ms": round(health_ms, 1), "sessions": health.get("sessions"),
                            "frames": sum(frames),
                            "caps_full": all(st["history"]["dropped"] > 0 for st in states)})
            if elapsed >= next_report:
                print(f"soak: {elapsed:6.0f}/{args.seconds:.0f} s  RSS {samples[-1]['rss_mb']:.0f} MB  "
                      f"fds {samples[-1]['fds']}  frames {sum(frames)}  errors {len(stats.errors)}", flush=True)
                next_report += 30
            time.sleep(args.sample_s)
        stop.set()
        final_states = [api.session(sid) for sid, _ in sids]
        for sid, _ in sids:
            api.delete_session(sid)
        for t in threads:
            t.join(timeout=60)
        # Every connection of a deleted session is let go of.
        deadline = time.monotonic() + 120
        while fds(pid) > fds_idle + 4 and time.monotonic() < deadline:
            time.sleep(1)
        fds_after = fds(pid)
    returncode = server.returncode

    # Memory is judged once every session's history has reached its cap (frames dropped): over
    # the second half of that steady phase, so that the allocator has settled.
    full = [k for k, s in enumerate(samples) if s["caps_full"]]
    steady_from = samples[full[0]]["t_s"] if full else None
    steady = samples[full[0]:] if full else []
    half = steady[len(steady) // 2:]
    if len(half) >= 2:
        rss_half_start = statistics.median([s["rss_mb"] for s in half[: max(1, len(half) // 10)]])
        rss_half_end = statistics.median([s["rss_mb"] for s in half[-max(1, len(half) // 10):]])
        growth = 100 * (rss_half_end - rss_half_start) / rss_half_start
    else:
        growth = float("inf")  # the caps never filled: run longer
    steady_growth = (100 * (steady[-1]["rss_mb"] - steady[0]["rss_mb"]) / steady[0]["rss_mb"]) if steady else None
    errors_in_sessions = [s["id"] for s in final_states if s["status"] == "error"]
    health_ms = [s["health_ms"] for s in samples if s["health_ms"] == s["health_ms"]]
    verdict = {
        "flat_rss": growth < args.rss_growth_pct,
        "no_error": not stats.errors and not errors_in_sessions and stats.rest_5xx == 0 and returncode == 0,
        "no_stall": stats.max_gap_s <= args.stall_s,
        "bounded_fds": fds_after <= fds_idle + 4,
    }
    figures = {
        "seconds": args.seconds, "sessions": args.sessions, "clients_per_session": args.clients,
        "frames_received_by_readers": stats.frames, "frames_simulated": samples[-1]["frames"] if samples else 0,
        "max_reader_gap_s": round(stats.max_gap_s, 2), "rest_calls": stats.rest_calls, "rest_5xx": stats.rest_5xx,
        "stalled_connections": stats.stalled_connections, "vanished_connections": stats.vanished_connections,
        "rss_mb_min": min(s["rss_mb"] for s in samples), "rss_mb_max": max(s["rss_mb"] for s in samples),
        "history_caps_full_at_s": steady_from,
        "rss_mb_when_caps_full": steady[0]["rss_mb"] if steady else None,
        "rss_steady_growth_pct": round(steady_growth, 2) if steady_growth is not None else None,
        "rss_steady_second_half_growth_pct": round(growth, 2),
        "health_ms_median": round(statistics.median(health_ms), 1), "health_ms_max": round(max(health_ms), 1),
        "fds_idle": fds_idle, "fds_max": max(s["fds"] for s in samples), "fds_after_delete": fds_after,
        "server_exit_status": returncode, "errors": stats.errors, "sessions_in_error": errors_in_sessions,
    }
    report = {"benchmark": "soak", "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
              "command": command, "binary": str(FLOWCLIP_BIN), "machine": machine(), "figures": figures,
              "verdict": verdict, "samples": samples}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "soak.json").write_text(json.dumps(report, indent=1) + "\n")
    ok = all(verdict.values())
    md = [f"# Soak: {args.sessions} sessions × {args.clients} clients for {args.seconds:.0f} s", "",
          f"- date: {report['date']}", f"- machine: {report['machine']['cpu']}, {report['machine']['cores']} cores",
          f"- command: `{command}`", f"- verdict: **{'pass' if ok else 'FAIL'}** "
          + ", ".join(f"{k} {'yes' if v else 'NO'}" for k, v in verdict.items()), "",
          "| figure | value |", "|---|---|"]
    md += [f"| {k} | {v} |" for k, v in figures.items() if k not in ("errors", "sessions_in_error")]
    if stats.errors:
        md += ["", "## Errors", ""] + [f"- `{e}`" for e in stats.errors]
    md += ["", "RSS over time (s: MB): " + ", ".join(f"{s['t_s']:.0f}: {s['rss_mb']:.0f}"
                                                       for s in samples[:: max(1, len(samples) // 20)])]
    (out / "soak.md").write_text("\n".join(md) + "\n")
    print("\n".join(md[:8]))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
