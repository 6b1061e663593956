"""Output locations of `flowclip-batch` (flowclip.batch) that are URLs: `s3://bucket/path`,
`gs://...`, `abfs://...`, `file:///...`: any file system of fsspec whose package is installed on the
client and on every worker (s3fs, gcsfs, adlfs...).

A task still runs in a local temporary folder. Its files are then uploaded into a hidden sibling,
`OUT/.<id>.stage-<token>/`, and moved one by one to `OUT/<id>/`, task.json last: object stores have
no atomic rename of a folder, so a task is complete exactly when `OUT/<id>/task.json` exists. A
partial upload or move leaves no task.json and never counts; the next attempt overwrites what it
left (the same task writes the same files) and the batch removes the hidden folders.

Credentials and options come from the environment of the client and the workers as fsspec reads
them (AWS_* for s3fs, GOOGLE_APPLICATION_CREDENTIALS for gcsfs, FSSPEC_S3='{"endpoint_url": ...}'):
the job spec holds no secret.
"""

from __future__ import annotations

import dataclasses
import json
import os
import posixpath
import re
import secrets
import tempfile
from pathlib import Path

COMPLETE = "task.json"
_URL = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]+)://")
_STAGE = re.compile(r"^\..+\.stage-[^/]+$")


def is_url(where) -> bool:
    """Whether an output location is a URL (fsspec) rather than a local path."""
    return isinstance(where, URLPath) or (isinstance(where, str) and _URL.match(where) is not None)


@dataclasses.dataclass(frozen=True)
class URLPath:
    """A folder of an fsspec file system, with the few pathlib operations flowclip.batch uses on the
    folders of its tasks (/, parent, name, str)."""

    url: str

    def __str__(self) -> str:
        return self.url

    def __truediv__(self, name: str) -> URLPath:
        return URLPath(f"{self.url.rstrip('/')}/{name}")

    @property
    def parent(self) -> URLPath:
        return URLPath(self.url.rstrip("/").rsplit("/", 1)[0])

    @property
    def name(self) -> str:
        return self.url.rstrip("/").rsplit("/", 1)[1]


def output(url: str) -> URLPath:
    """The spec's `out` as a URL, checked on the client: fsspec and the protocol's package are
    installed, and the file system is one the workers share."""
    from flowclip.batch import SpecError

    protocol = _URL.match(url).group(1).lower()
    try:
        import fsspec
    except ImportError:
        raise SpecError(f"out: {url} is a URL: it needs fsspec (pip install \"flowclip[batch]\")") from None
    if protocol == "memory":
        raise SpecError(f"out: {url}: memory:// is each process's own memory; the workers' files would not "
                        "reach the client (use a shared folder, file:// or an object store)")
    try:
        fs, path = fsspec.core.url_to_fs(url)
    except ImportError as e:
        from fsspec.registry import known_implementations

        package = known_implementations.get(protocol, {}).get("class", "").split(".")[0]
        if not package:
            raise SpecError(f"out: {url}: {e}") from None
        raise SpecError(f"out: {url}: {protocol}:// needs the {package} package on the client and every worker "
                        f"(pip install {package})") from None
    except ValueError as e:
        raise SpecError(f"out: {url}: {e}") from None
    if not path.strip("/"):
        raise SpecError(f"out: {url}: a folder under the file system's root, e.g. {url.rstrip('/')}/batch")
    return URLPath(url.rstrip("/"))


def _fs(where):
    """The file system of a URL and the path in it, with no listing cached from before."""
    import fsspec

    fs, path = fsspec.core.url_to_fs(str(where))
    fs.invalidate_cache()
    return fs, path.rstrip("/")


def read_complete(folder: URLPath) -> dict | None:
    """A task's task.json, None while the task is not complete."""
    fs, path = _fs(folder)
    try:
        return json.loads(fs.cat_file(f"{path}/{COMPLETE}"))
    except FileNotFoundError:
        return None


def upload(local: Path, folder: URLPath) -> None:
    """A finished task's local folder to `folder`: uploaded into a hidden sibling, then moved file by
    file, task.json last."""
    fs, dest = _fs(folder)
    parent, name = posixpath.split(dest)
    stage = f"{parent}/.{name}.stage-{os.getpid()}-{secrets.token_hex(4)}"
    files = sorted(p.relative_to(local).as_posix() for p in local.rglob("*") if p.is_file() and p.name != COMPLETE)
    if not (local / COMPLETE).is_file():
        raise RuntimeError(f"{local}: no {COMPLETE}: the task did not finish")
    files.append(COMPLETE)
    try:
        for rel in files:
            fs.makedirs(posixpath.dirname(f"{stage}/{rel}"), exist_ok=True)
            fs.put_file(str(local / rel), f"{stage}/{rel}")
        if fs.exists(f"{dest}/{COMPLETE}"):  # another attempt of the same task completed it meanwhile
            return
        for rel in files:
            fs.makedirs(posixpath.dirname(f"{dest}/{rel}"), exist_ok=True)
            fs.mv(f"{stage}/{rel}", f"{dest}/{rel}")
    finally:
        try:
            if fs.exists(stage):
                fs.rm(stage, recursive=True)
        except OSError:
            pass  # the next batch removes it


def run_task(task, binary: str, run_local) -> dict:
    """A task whose folder is a URL: skipped when complete, else run whole by `run_local` in a local
    temporary folder, then uploaded."""
    summary = read_complete(task.folder)
    if summary is not None:
        return {**summary, "skipped": True}
    with tempfile.TemporaryDirectory(prefix=f"flowclip-task-{task.id}-") as tmp:
        local = Path(tmp) / task.id
        result = run_local(dataclasses.replace(task, folder=local), binary)
        upload(local, task.folder)
    return result


def prepare(out: URLPath) -> None:
    """The batch's output folder (a no-op on object stores, which have no folders)."""
    fs, path = _fs(out)
    fs.makedirs(path, exist_ok=True)


def remove_stages(out: URLPath) -> None:
    """The hidden folders of attempts that did not finish: never complete."""
    fs, path = _fs(out)
    try:
        entries = fs.ls(path, detail=False)
    except FileNotFoundError:
        return
    for entry in entries:
        if _STAGE.match(posixpath.basename(entry.rstrip("/"))):
            try:
                fs.rm(entry, recursive=True)
            except FileNotFoundError:
                pass


def write_table(out: URLPath, folders: list, table: dict) -> None:
    """batch.json, once every task's task.json is in place."""
    fs, path = _fs(out)
    missing = [f.name for f in folders if not fs.exists(f"{path}/{f.name}/{COMPLETE}")]
    if missing:
        raise RuntimeError(f"{out}: tasks not complete (no {COMPLETE}): {', '.join(missing)}")
    staged = f"{path}/.batch.json.{os.getpid()}-{secrets.token_hex(4)}"
    fs.pipe_file(staged, json.dumps(table, indent=1).encode())
    fs.mv(staged, f"{path}/batch.json")
