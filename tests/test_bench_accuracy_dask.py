"""`flowclip bench accuracy --local N` and `flowclip-batch commands` (docs/batch.md): the sweep's
points as tasks of a real LocalCluster of 2 worker processes give the figures of the sequential
sweep, point by point (the solver is bit-deterministic at a given thread count: both run one OpenMP
thread per point); a scheduler that cannot be reached or a missing flowclip-batch stops the sweep
with a message naming the option, and no traceback; Ctrl-C keeps the points measured. The generic
runner: a command that fails or leaves an output missing is a result (no folder), a complete one is
skipped on a re-run.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from flowclip.commands import load_commands, run_commands
from repo_paths import FLOWCLIP_BIN, ROOT
from service_helpers import wait_until

# flowclip-batch of the Python running the tests: the package under test, whatever FLOWCLIP_BIN is.
BATCH = Path(sys.executable).parent / "flowclip-batch"
# Figures that depend on the time a run took, not on what it simulated.
TIMING = {"wall_s_per_sim_s", "ms_per_frame", "us_per_particle_step", "cpu_s_per_sim_s", "load_avg",
          "preset", "front_avg_density_error", "front_max_density_error", "front_volume_drift",
          "front_surge_front_rms", "front_fidelity"}


def sweep(out, template_dir, *extra, env=None):
    cmd = [str(FLOWCLIP_BIN), "bench", "accuracy", "--quick", "--threads", "1", "--no-plots", "--out", str(out),
           "--templates", str(template_dir), *extra]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=3600, cwd=ROOT,
                          env={**os.environ, "FLOWCLIP_BATCH": str(BATCH), **(env or {})})


def rows(out):
    with (out / "accuracy.csv").open(newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.heavy
def test_the_sweep_on_a_local_cluster_equals_the_sequential_sweep(quick_accuracy, template_dir, tmp_path):
    seq_dir = quick_accuracy[0]  # the study's sequential sweep (tests/conftest.py)
    dask = sweep(tmp_path / "dask", template_dir, "--local", "2")
    assert dask.returncode == 0, dask.stderr
    a, b = rows(seq_dir), rows(tmp_path / "dask")
    assert len(a) == len(b) >= 10
    for x, y in zip(a, b):
        assert x["status"] == y["status"] == "ok", (x, y)
        for col in x:
            if col not in TIMING:
                assert x[col] == y[col], f"point {x['id']} ({x['group']} {x['scene']}): {col} {x[col]} != {y[col]}"
        for col in ("wall_s_per_sim_s", "cpu_s_per_sim_s"):  # measured on the worker, not left out
            assert float(y[col]) > 0, (col, y)
    # The surge fronts too: every exported frame's front, point by point.
    assert (seq_dir / "surge_fronts.csv").read_text() == (tmp_path / "dask" / "surge_fronts.csv").read_text()
    # One progress line per point, the runner's own per task, and the report says where the points ran.
    n = len(b)
    for i in range(1, n + 1):
        assert f"[{i}/{n}] " in dask.stderr
    assert f"commands: {n}/{n} " in dask.stderr
    assert "Traceback" not in dask.stderr
    md = (tmp_path / "dask" / "accuracy.md").read_text()
    assert "run as tasks of a Dask LocalCluster of 2 worker processes" in md
    assert "--local 2" in json.loads((tmp_path / "dask" / "presets.json").read_text())["source"]
    # The tasks' folders are gone: only the report is left in --out.
    assert not [p for p in (tmp_path / "dask").iterdir() if p.name.startswith(".")]


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_an_unreachable_scheduler_is_named_without_a_traceback(template_dir, tmp_path):
    address = f"tcp://127.0.0.1:{free_port()}"
    # Dask's own setting: how long to keep trying to connect (30 s by default).
    r = sweep(tmp_path / "out", template_dir, "--scheduler", address,
              env={"DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "2s"})
    assert r.returncode == 2, r.stderr
    assert f"--scheduler {address}: cannot reach the scheduler" in r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "out" / "accuracy.csv").exists()
    assert not [p for p in (tmp_path / "out").iterdir() if p.name.startswith(".")]


def test_a_missing_batch_command_is_named(template_dir, tmp_path):
    r = sweep(tmp_path / "out", template_dir, "--local", "2", "--batch-command", str(tmp_path / "no-such"))
    assert r.returncode == 2 and f"--batch-command: '{tmp_path / 'no-such'}' is not an executable file" in r.stderr
    r = sweep(tmp_path / "out", template_dir, "--local", "2", env={"FLOWCLIP_BATCH": str(tmp_path / "nope")})
    assert r.returncode == 2 and "FLOWCLIP_BATCH: " in r.stderr and "Traceback" not in r.stderr


def test_the_commands_runner_reports_failures_and_skips_what_is_complete(tmp_path):
    listing = tmp_path / "list.json"
    listing.write_text(json.dumps({"commands": [
        {"id": "ok", "argv": ["/bin/sh", "-c", "echo $OMP_NUM_THREADS > out.txt; echo done >&2"], "cwd": "w/ok",
         "outputs": ["out.txt"], "threads": 3},
        {"id": "fails", "argv": ["/bin/sh", "-c", "echo broken >&2; exit 3"], "cwd": "w/fails"},
        {"id": "silent", "argv": ["/bin/sh", "-c", "true"], "cwd": "w/silent", "outputs": ["missing.txt"]},
    ]}))
    commands = load_commands(listing)
    results = run_commands(commands, local=2, log=lambda _: None)
    ok, fails, silent = results
    assert ok["ok"] and ok["status"] == 0 and ok["stderr_tail"] == "done" and not ok["skipped"]
    assert (tmp_path / "w" / "ok" / "out.txt").read_text().strip() == "3"
    assert not fails["ok"] and fails["status"] == 3 and fails["stderr_tail"] == "broken"
    assert not silent["ok"] and silent["status"] == 0 and silent["missing"] == ["missing.txt"]
    # A folder exactly for the complete command; nothing hidden left behind.
    assert sorted(p.name for p in (tmp_path / "w").iterdir()) == ["ok"]
    again = run_commands(load_commands(listing), local=1, log=lambda _: None)
    assert again[0]["skipped"] and not again[1]["skipped"]
    # The command line: exit 1 when some command failed, the results beside the list.
    r = subprocess.run([str(BATCH), "commands", str(listing), "--local", "1", "--progress", "json"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 1, r.stderr
    events = [json.loads(line) for line in r.stdout.splitlines()]
    assert events[0] == {"event": "plan", "commands": ["ok", "fails", "silent"]}
    assert events[-1] == {"event": "end", "commands": 3, "failed": ["fails", "silent"]}
    saved = json.loads((tmp_path / "list.results.json").read_text())["commands"]
    assert [c["id"] for c in saved] == ["ok", "fails", "silent"]


@pytest.mark.parametrize("entry, names", [
    ({"argv": [], "cwd": "w"}, "commands[0].argv: a non-empty list"),
    ({"argv": ["x"]}, "commands[0].cwd"),
    ({"argv": ["x"], "cwd": "w", "threads": 0}, "commands[0].threads: a positive integer"),
    ({"argv": ["x"], "cwd": "w", "colour": 1}, "commands[0].colour: unknown key"),
])
def test_a_command_list_that_cannot_run_is_refused_naming_the_entry(tmp_path, entry, names):
    listing = tmp_path / "list.json"
    listing.write_text(json.dumps([entry]))
    r = subprocess.run([str(BATCH), "commands", str(listing), "--local", "1"], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 2 and names in r.stderr and "Traceback" not in r.stderr


@pytest.mark.heavy
def test_ctrl_c_stops_the_cluster_and_keeps_the_points_measured(template_dir, tmp_path):
    """Ctrl-C reaches the whole process group (the sweep, the runner, its workers and their runs): the
    sweep writes the points whose runs finished and exits 130, and nothing of the batch is left."""
    out = tmp_path / "out"
    cmd = [str(FLOWCLIP_BIN), "bench", "accuracy", "--quick", "--no-plots", "--out", str(out), "--templates",
           str(template_dir), "--local", "2"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                            env={**os.environ, "FLOWCLIP_BATCH": str(BATCH)}, start_new_session=True)
    lines = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stderr), daemon=True)
    reader.start()
    try:
        # Once the runner has two results, the batch is under way.
        wait_until(lambda: any(line.startswith("commands: 2/") for line in lines), timeout=600,
                   what="two finished tasks")
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=600)
        reader.join(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    stderr = "".join(lines)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr
    measured = rows(out)
    assert len(measured) >= 2 and all(r["status"] == "ok" for r in measured), stderr
    # The last tasks may have finished before Ctrl-C reached the runner: then nothing was cut short.
    assert f"interrupted after {len(measured)} points" in stderr or len(measured) == 18, stderr
    assert not [p for p in out.iterdir() if p.name.startswith(".")]
