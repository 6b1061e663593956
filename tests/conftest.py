"""Fixtures of the service tests (tests/test_service_*.py).

`server` is one `flowclip serve` per test module (FLOWCLIP_BIN, default
build/flowclip, started by the installed flowclip package, clients/python)
with copies of the 2D templates and the scenes in a temporary directory
(the tests delete templates and save scenes), the small recipes of
`recipe_dir`, --max-body-mb 1, and checked to exit 0 on SIGINT. Every
`client` validates each response against proto/openapi.yaml as it arrives.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from repo_paths import FLOWCLIP_BIN, ROOT

try:
    from flowclip import FlowClipServer
except ModuleNotFoundError as e:
    raise ModuleNotFoundError(f"{e}: the Python client (clients/python) is installed into build/venv by "
                              "make setup (tools/setup.sh), or by pip install clients/python") from e
from openapi_check import OpenApiChecker
from service_helpers import small_recipe

# The package's FlowClipServer starts $FLOWCLIP_BIN: the executable under test.
os.environ["FLOWCLIP_BIN"] = str(FLOWCLIP_BIN)

TEMPLATES_2D = ("drop2d", "column2d", "jet2d")
MAX_BODY_MB = 1


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "heavy: minutes of simulation under the sanitizers (benchmark sweeps, the batch runner's own "
        "logic, physics read from exports); server/fuzz/pytest_sanitized.sh leaves these out (-m 'not heavy'): "
        "the input handling the sanitized run is for is in the other tests, and ctest runs the solvers")


@pytest.fixture(scope="session")
def openapi():
    return OpenApiChecker()


@pytest.fixture(scope="session")
def template_dir(tmp_path_factory):
    """The 2D templates (recorded here when `make templates` has not)."""
    assert FLOWCLIP_BIN.exists(), f"{FLOWCLIP_BIN} is missing: build first (make build) or set FLOWCLIP_BIN"
    out = tmp_path_factory.mktemp("templates")
    for name in TEMPLATES_2D:
        src = ROOT / "templates" / f"{name}.h5"
        if src.exists():
            shutil.copy(src, out / src.name)
        else:
            subprocess.run([str(FLOWCLIP_BIN), "record", str(ROOT / "templates" / "recipes" / f"{name}.json"),
                            "--templates", str(out), "--force", "--quiet"], check=True, timeout=300)
    return out


@pytest.fixture(scope="session")
def quick_accuracy(template_dir, tmp_path_factory):
    """One `flowclip bench accuracy --quick` sweep (with its plots) for every test that reads one: the
    study's own and the Dask sweep's comparison. One thread: on a machine shared with busy processes,
    OpenMP's barriers wait for descheduled threads; the timeout only catches a hang."""
    out = tmp_path_factory.mktemp("accuracy")
    cmd = [str(FLOWCLIP_BIN), "bench", "accuracy", "--quick", "--threads", "1", "--out", str(out),
           "--templates", str(template_dir)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=3600, cwd=ROOT)
    assert proc.returncode == 0, f"{' '.join(cmd)} exited with {proc.returncode}:\n{proc.stdout}\n{proc.stderr}"
    return out, proc


@pytest.fixture(scope="session")
def scene_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("scenes")
    for src in (ROOT / "scenes").glob("*.json"):
        shutil.copy(src, out / src.name)
    return out


@pytest.fixture(scope="session")
def recipe_dir(tmp_path_factory):
    """Recipes of the small tank: `tiny` records template tiny_tpl (5 frames) at once, `endless`
    (endless_tpl, 100 000 frames) runs until cancelled."""
    out = tmp_path_factory.mktemp("recipes")
    for name, template, frames in (("tiny", "tiny_tpl", 5), ("endless", "endless_tpl", 100000)):
        (out / f"{name}.json").write_text(json.dumps(small_recipe(name, template, frames)))
    return out


# What a stream waits for a message by default: a loaded machine or the
# sanitizers make frames slow, never wrong (tests that expect silence pass their own).
STREAM_TIMEOUT = 120.0


# flowclip-batch of the test venv: the server's render jobs run through it (one local worker).
BATCH_COMMAND = Path(sys.executable).parent / "flowclip-batch"


def job_args(workers=1):
    return ["--batch-command", str(BATCH_COMMAND), "--job-workers", str(workers)]


@pytest.fixture(scope="module")
def server(template_dir, scene_dir, recipe_dir, tmp_path_factory):
    with FlowClipServer(template_dir, scene_dir, tmp_path_factory.mktemp("exports"),
                        max_body_mb=MAX_BODY_MB, recipes=recipe_dir, extra_args=job_args()) as s:
        plain = s.stream
        s.stream = lambda sid, **kw: plain(sid, **{"timeout": STREAM_TIMEOUT, **kw})
        yield s
    assert s.returncode == 0, "flowclip serve did not stop cleanly on SIGINT:\n" + "\n".join(s.output[-30:])


@pytest.fixture
def client(server, openapi):
    c = server.client()
    c.observers.append(openapi.observe)
    yield c
    # Sessions a test leaves behind would count against --max-sessions.
    for st in c.sessions():
        c.delete_session(st["id"])
