"""`flowclip-batch commands LIST.json`: independent commands as tasks of a Dask distributed cluster
(a LocalCluster of N worker processes, or a running scheduler), for a program that has its own list
of runs to make, such as `flowclip bench accuracy --local N` (docs/batch.md).

The list (JSON), a list of commands or an object {"commands": [...]}:

    {"commands": [
      {"id": "p0",                                  # unique; default: the index
       "argv": ["/abs/flowclip", "run", "/abs/scene.json", "--stats", "stats.json"],
       "cwd": "work/p0",                            # the command's folder; relative: to the list's folder
       "outputs": ["stats.json"],                   # files the command must leave in its folder
       "threads": 1}                                # OMP_NUM_THREADS of the command (default: unset)
    ]}

A command runs in a hidden staging folder beside `cwd`, renamed to `cwd` when it exited 0 with every
output present: a command is complete exactly when its folder exists with `command.json` (its record),
and a re-run skips it. A failed command leaves no folder; its result says why (exit status, stderr
tail). Each command is killed with the worker that runs it (PR_SET_PDEATHSIG), and a task whose worker
died is run again elsewhere.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from .batch import SpecError, _die_with_parent

RECORD = "command.json"
TAIL_LINES = 20


class CommandsError(SpecError):
    """A command list or cluster that cannot run; the message names the command or option."""


def load_commands(path) -> list[dict]:
    """The commands of a list file, checked, with absolute folders (relative ones: to the list's folder)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except OSError as e:
        raise CommandsError(f"{path}: {e.strerror}") from None
    except ValueError as e:
        raise CommandsError(f"{path}: not valid JSON: {e}") from None
    commands = data.get("commands") if isinstance(data, dict) else data
    if not isinstance(commands, list):
        raise CommandsError(f"{path}: a list of commands, or an object with one under \"commands\"")
    base = path.resolve().parent
    out, ids, folders = [], set(), set()
    for n, c in enumerate(commands):
        where = f"{path}: commands[{n}]"
        if not isinstance(c, dict):
            raise CommandsError(f"{where}: an object (argv, cwd, outputs, threads)")
        unknown = sorted(set(c) - {"id", "argv", "cwd", "outputs", "threads"})
        if unknown:
            raise CommandsError(f"{where}.{unknown[0]}: unknown key; expected id, argv, cwd, outputs, threads")
        argv = c.get("argv")
        if not isinstance(argv, list) or not argv or not all(isinstance(a, str) for a in argv):
            raise CommandsError(f"{where}.argv: a non-empty list of strings")
        if not isinstance(c.get("cwd"), str) or not c["cwd"]:
            raise CommandsError(f"{where}.cwd: the command's folder (a path)")
        outputs = c.get("outputs", [])
        if not isinstance(outputs, list) or not all(isinstance(o, str) and o for o in outputs):
            raise CommandsError(f"{where}.outputs: a list of file names in the command's folder")
        threads = c.get("threads")
        if threads is not None and (not isinstance(threads, int) or isinstance(threads, bool) or threads < 1):
            raise CommandsError(f"{where}.threads: a positive integer")
        cid = str(c.get("id", n))
        if cid in ids:
            raise CommandsError(f"{where}.id: {cid!r} is given twice")
        folder = (base / c["cwd"]).resolve()
        if folder in folders:
            raise CommandsError(f"{where}.cwd: {folder} is another command's folder too")
        if folder.exists() and not (folder / RECORD).is_file():
            raise CommandsError(f"{where}.cwd: {folder} exists and is not a complete command's folder")
        ids.add(cid)
        folders.add(folder)
        out.append({"id": cid, "argv": list(argv), "cwd": str(folder), "outputs": list(outputs),
                    "threads": threads})
    return out


def _staging_glob(folder: Path) -> str:
    return f".{folder.name}.stage-*"


def run_command(command: dict) -> dict:
    """One command on a worker: skipped when its folder is complete, else run in a hidden folder that
    is renamed into place when the command exited 0 with its outputs. Raises only when the folder
    cannot be made (Dask then retries); a command that fails is a result, not an exception."""
    folder = Path(command["cwd"])
    record = folder / RECORD
    if record.is_file():
        return {**json.loads(record.read_text()), "skipped": True}
    folder.parent.mkdir(parents=True, exist_ok=True)
    staging = folder.parent / f".{folder.name}.stage-{os.getpid()}-{secrets.token_hex(4)}"
    staging.mkdir()
    env = dict(os.environ)
    if command.get("threads"):
        env["OMP_NUM_THREADS"] = str(command["threads"])
    result = {"id": command["id"], "argv": command["argv"], "status": None, "ok": False, "wall_s": 0.0,
              "cpu_s": 0.0, "load": 0.0, "stderr_tail": "", "missing": [], "skipped": False}
    try:
        load0 = os.getloadavg()[0]
        t0 = time.monotonic()
        try:
            proc = subprocess.Popen(command["argv"], cwd=staging, env=env, stdin=subprocess.DEVNULL,
                                    stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, errors="replace",
                                    preexec_fn=_die_with_parent)
        except OSError as e:  # not found, not executable: the command's own failure, as a shell's 127
            result.update(status=127, stderr_tail=f"{command['argv'][0]}: {e.strerror}")
            return result
        tail = []
        for line in proc.stderr:
            tail = (tail + [line.rstrip("\n")])[-TAIL_LINES:]
        proc.stderr.close()
        # wait4: this child's own CPU time, whatever else the worker's process runs.
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        result.update(status=proc.returncode, wall_s=time.monotonic() - t0,
                      cpu_s=usage.ru_utime + usage.ru_stime, load=0.5 * (load0 + os.getloadavg()[0]),
                      stderr_tail="\n".join(tail))
        result["missing"] = [o for o in command["outputs"] if not (staging / o).exists()]
        if proc.returncode != 0 or result["missing"]:
            return result
        result["ok"] = True
        (staging / RECORD).write_text(json.dumps(result, indent=1))
        try:
            staging.rename(folder)  # the command is complete exactly when its folder exists
        except OSError:
            if not record.is_file():  # not another attempt's complete folder
                raise
        return result
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)


def _remove_leftovers(commands: list[dict]) -> None:
    """A killed attempt's hidden folders: never complete."""
    for c in commands:
        folder = Path(c["cwd"])
        if folder.parent.is_dir():
            for left in folder.parent.glob(_staging_glob(folder)):
                shutil.rmtree(left, ignore_errors=True)


def run_commands(commands: list[dict], *, local=None, scheduler=None, retries=2, log=None, event=None,
                 connect_timeout=None) -> list[dict]:
    """Runs every command as a task of a LocalCluster of `local` worker processes (one task at a time
    each) or of the scheduler at `scheduler`; the results in the list's order. On KeyboardInterrupt the
    results so far are in the exception's `results` (None for the commands not finished). Reaching the
    scheduler gives up after `connect_timeout` seconds (default: Dask's distributed.comm.timeouts.connect,
    30 s unless DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT says otherwise)."""
    from distributed import Client, LocalCluster, as_completed

    log = log or (lambda line: print(line, file=sys.stderr, flush=True))
    event = event or (lambda e: None)
    _remove_leftovers(commands)
    event({"event": "plan", "commands": [c["id"] for c in commands]})
    results = [None] * len(commands)
    if not commands:
        return results
    cluster = None
    if scheduler is None:
        # Its workers start with Ctrl-C ignored: it reaches this client, which closes them (and so their commands).
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            # ":0": the scheduler's HTTP server on a free port (None still takes 8787, warning when it is busy).
            cluster = LocalCluster(n_workers=local or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                                   dashboard_address=":0")
        finally:
            signal.signal(signal.SIGINT, previous)
    try:
        try:
            timeout = {} if connect_timeout is None else {"timeout": connect_timeout}
            client = Client(cluster if cluster is not None else scheduler, **timeout)
        except (OSError, ValueError) as e:
            if scheduler is None:
                raise
            raise CommandsError(f"--scheduler {scheduler}: cannot reach the scheduler: {e}") from None
        with client:
            futures = [client.submit(run_command, c, key=f"flowclip-command-{c['id']}-{secrets.token_hex(4)}",
                                     pure=False, retries=retries) for c in commands]
            index = {f.key: n for n, f in enumerate(futures)}
            try:
                for done, future in enumerate(as_completed(futures), 1):
                    result = future.result()
                    results[index[future.key]] = result
                    missing = f", missing {', '.join(result['missing'])}" if result["missing"] else ""
                    state = ("skipped (complete)" if result["skipped"] else
                             f"exit {result['status']}{missing}, {result['wall_s']:.1f} s")
                    log(f"commands: {done}/{len(commands)} {result['id']} {state}")
                    event({"event": "done", **{k: v for k, v in result.items() if k != "argv"}})
            except KeyboardInterrupt as e:
                e.results = results
                raise
    finally:
        if cluster is not None:
            cluster.close()
        _remove_leftovers(commands)  # interrupted too: what is hidden is a stopped attempt's
    return results


def write_results(path, results: list) -> None:
    path = Path(path)
    staged = path.parent / f".{path.name}.{os.getpid()}"
    staged.write_text(json.dumps({"commands": results}, indent=1))
    staged.replace(path)


def add_parser(sub) -> None:
    """`flowclip-batch commands`'s arguments, on batch.py's sub-command parser."""
    p = sub.add_parser("commands", help="independent commands (a JSON list) as tasks of a Dask cluster")
    p.add_argument("list", help="LIST.json: the commands (argv, cwd, outputs, threads); docs/batch.md")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--local", type=int, help="a LocalCluster of N worker processes")
    where.add_argument("--scheduler", help="a running scheduler's address, tcp://HOST:8786")
    p.add_argument("--results", help="where the per-command results go (default: LIST.results.json beside LIST)")
    p.add_argument("--progress", choices=["text", "json"], default="text",
                   help="json: one JSON object per line on stdout (plan, done, end, error); text lines go to stderr")


def main(a) -> int:
    """Runs `flowclip-batch commands` with its parsed arguments: 0 when every command succeeded,
    1 when some failed (their results say why), 2 for a list or cluster that cannot run, 130 on Ctrl-C."""
    as_json = a.progress == "json"

    def emit(e):
        if as_json:
            print(json.dumps(e), flush=True)

    def fail(message, code):
        emit({"event": "error", "message": message})
        print(f"flowclip-batch: {message}", file=sys.stderr, flush=True)
        return code

    if a.local is not None and a.local < 1:
        return fail(f"--local {a.local}: the number of worker processes, at least 1", 2)
    results_path = Path(a.results) if a.results else Path(a.list).with_suffix(".results.json")
    try:
        commands = load_commands(a.list)
        results = run_commands(commands, local=a.local, scheduler=a.scheduler, event=emit)
    except CommandsError as e:
        return fail(str(e), 2)
    except KeyboardInterrupt as e:
        partial = getattr(e, "results", None)
        if partial is None:
            return fail("interrupted before any command finished", 130)
        write_results(results_path, partial)
        return fail(f"interrupted: {sum(r is not None for r in partial)} commands finished, in {results_path}", 130)
    write_results(results_path, results)
    failed = [r["id"] for r in results if not r["ok"]]
    emit({"event": "end", "commands": len(results), "failed": failed})
    print(f"flowclip-batch: {len(results)} commands, {len(results) - len(failed)} complete"
          f"{', failed: ' + ', '.join(failed) if failed else ''}; results in {results_path}", file=sys.stderr)
    return 1 if failed else 0
