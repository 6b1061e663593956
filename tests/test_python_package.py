"""The Python client as a package (clients/python): what is installed carries the repository's REST
contract and wire code, not a reference to the checkout; the package builds from clients/python and
proto/ alone, without network (a wheel, an sdist that builds on its own, an editable install); and
a built wheel installs into a fresh venv and imports there.

The fresh venvs get no network: the package's dependencies are the test venv's own, seen through a
directory of links to its site-packages (flowclip left out)."""

from __future__ import annotations

import importlib.metadata
import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tarfile
import tomllib
import zipfile
from pathlib import Path

import pytest
import yaml

import flowclip
from repo_paths import ROOT

PACKAGE = ROOT / "clients" / "python"
PROTO = ROOT / "proto"
MODULES = {"__init__.py", "batch.py", "client.py", "codec.py", "commands.py", "operations.py", "server.py", "storage.py",
           "stream.py"}
BUILD_TIMEOUT = 300


def _requirement_pins():
    pins = {}
    for line in (ROOT / "requirements.txt").read_text().splitlines():
        m = re.match(r"([A-Za-z0-9_.-]+)==(\S+)", line.strip())
        if m:
            pins[m.group(1).lower()] = m.group(2)
    return pins


def _flatc_wire(out: Path) -> dict[str, bytes]:
    """flowclip/wire as flatc generates it from proto/ now: file name -> bytes."""
    schemas = sorted(str(p) for p in PROTO.glob("*.fbs"))
    subprocess.run(["flatc", "--python", "-I", str(PROTO), "-o", str(out), *schemas], check=True, timeout=60)
    return {p.name: p.read_bytes() for p in (out / "flowclip" / "wire").glob("*.py")}


def _env():
    """The environment of a build: no proto/ named by hand, so the build finds its own."""
    return {k: v for k, v in os.environ.items() if k not in ("FLOWCLIP_PROTO_DIR", "PYTHONPATH")}


def _pip(python, *args, cwd=None):
    run = subprocess.run([str(python), "-m", "pip", "--disable-pip-version-check", "--no-input", "-q", *args],
                         capture_output=True, text=True, timeout=BUILD_TIMEOUT, cwd=cwd, env=_env())
    assert run.returncode == 0, (f"pip {' '.join(args)}: the build runs on the venv's setuptools, pinned in "
                                 f"requirements.txt (make setup installs it)\n{run.stdout}{run.stderr}")


@pytest.fixture(scope="module")
def source_copy(tmp_path_factory):
    """clients/python and proto/ as a fresh clone has them (no build output, nothing generated)."""
    root = tmp_path_factory.mktemp("checkout")
    generated = shutil.ignore_patterns("build", "dist", "*.egg-info", "__pycache__", "wire", "openapi.yaml", "proto")
    shutil.copytree(PACKAGE, root / "clients" / "python", ignore=generated)
    shutil.copytree(PROTO, root / "proto")
    return root


@pytest.fixture(scope="module")
def wheel(source_copy, tmp_path_factory):
    out = tmp_path_factory.mktemp("wheel")
    _pip(sys.executable, "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-w", str(out),
         str(source_copy / "clients" / "python"))
    (built,) = out.glob("flowclip-*.whl")
    return built


def _fresh_venv(where: Path) -> Path:
    """A new venv whose only packages are links to the test venv's, flowclip's aside; its python."""
    subprocess.run([getattr(sys, "_base_executable", sys.executable), "-m", "venv", "--without-pip", str(where)],
                   check=True, timeout=120)
    python = where / "bin" / "python"
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               check=True, capture_output=True, text=True).stdout.strip())
    deps = where / "deps"
    deps.mkdir()
    for entry in Path(sysconfig.get_paths()["purelib"]).iterdir():
        if not entry.name.lower().startswith(("flowclip", "__editable__", "_flowclip")):
            (deps / entry.name).symlink_to(entry)
    (site / "test_venv_deps.pth").write_text(f"{deps}\n")
    return python


def _inspect(python, cwd) -> dict:
    """What `import flowclip` finds in that python, run outside the checkout."""
    script = ("import json, flowclip, flowclip.wire as w\n"
              "from flowclip import ApiError, Client, FlowClipServer, Stream\n"
              "print(json.dumps({'file': flowclip.__file__, 'spec': str(flowclip.OPENAPI_SPEC), "
              "'wire': w.__file__, 'version': flowclip.__version__, 'operations': flowclip.OPERATIONS, "
              "'identifier': flowclip.encode_transport('step', steps=2)[4:8].decode()}))")
    run = subprocess.run([str(python), "-c", script], capture_output=True, text=True, timeout=120, cwd=cwd, env=_env())
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)


def _repo_operations():
    return {op: list(route) for op, route in flowclip.load_operations(PROTO / "openapi.yaml").items()}


def test_the_installed_package_carries_the_repositorys_spec():
    installed = Path(flowclip.__file__).resolve().parent
    assert flowclip.OPENAPI_SPEC == installed / "openapi.yaml"
    assert flowclip.OPENAPI_SPEC != (PROTO / "openapi.yaml").resolve()
    assert flowclip.OPENAPI_SPEC.read_bytes() == (PROTO / "openapi.yaml").read_bytes(), \
        "the installed flowclip package is older than proto/openapi.yaml: make setup reinstalls it"
    assert flowclip.OPERATIONS == flowclip.load_operations(PROTO / "openapi.yaml")
    assert flowclip.__version__ == str(yaml.safe_load(flowclip.OPENAPI_SPEC.read_text())["info"]["version"])


def test_the_installed_wire_code_is_flatc_of_the_schema(tmp_path):
    installed = Path(flowclip.__file__).resolve().parent / "wire"
    expected = _flatc_wire(tmp_path)
    assert "Envelope.py" in expected and "__init__.py" in expected
    found = {p.name: p.read_bytes() for p in installed.glob("*.py")}
    assert found == expected, \
        "the installed flowclip.wire is not flatc's output of proto/*.fbs: make setup reinstalls it"


def test_the_version_is_the_projects():
    cmake = re.search(r"project\(flowclip VERSION (\S+)", (ROOT / "server" / "CMakeLists.txt").read_text())
    assert cmake, "project(flowclip VERSION ...) not found in server/CMakeLists.txt"
    assert flowclip.__version__ == cmake.group(1), \
        "info.version of proto/openapi.yaml (the package's version) must be the project's (server/CMakeLists.txt)"
    assert importlib.metadata.version("flowclip") == flowclip.__version__


def test_dependencies_are_the_requirements_pins():
    project = tomllib.loads((PACKAGE / "pyproject.toml").read_text())
    pins = _requirement_pins()
    dependencies = project["project"]["dependencies"]
    assert {re.split(r"[<>=!~ ]", d)[0].lower() for d in dependencies} == \
        {"requests", "websockets", "numpy", "flatbuffers", "pyyaml"}
    optional = [d for group in project["project"].get("optional-dependencies", {}).values() for d in group]
    for dependency in dependencies + optional + project["build-system"]["requires"]:
        m = re.fullmatch(r"([A-Za-z0-9_.-]+)(>=|==)(\S+)", dependency)
        assert m, f"{dependency}: a lower bound (>=) of a dependency or a pin (==) of the build backend"
        pin = pins.get(m.group(1).lower())
        assert pin == m.group(3), f"{dependency} of clients/python/pyproject.toml is not requirements.txt's pin {pin}"
    assert project["project"]["requires-python"] == ">=3.11"
    assert "scripts" in project["project"], "the [project.scripts] table commands of the package go in"


def test_generated_files_are_not_tracked():
    tracked = subprocess.run(["git", "ls-files", "clients/python"], cwd=ROOT, capture_output=True, text=True,
                             check=True).stdout.split()
    assert "clients/python/setup.py" in tracked
    assert not [f for f in tracked if f.endswith("openapi.yaml") or "/wire/" in f or f.endswith(".fbs")], tracked
    probe = ["clients/python/flowclip/openapi.yaml", "clients/python/flowclip/wire/Frame.py",
             "clients/python/build/lib/flowclip/client.py", "clients/python/flowclip.egg-info/PKG-INFO"]
    ignored = subprocess.run(["git", "check-ignore", "--no-index", *probe], cwd=ROOT, capture_output=True, text=True)
    assert ignored.stdout.split() == probe, "not git-ignored: " + str(set(probe) - set(ignored.stdout.split()))


def test_the_wheel_carries_the_spec_and_the_wire_code(wheel, tmp_path):
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        assert z.read("flowclip/openapi.yaml") == (PROTO / "openapi.yaml").read_bytes()
        wire = {n.removeprefix("flowclip/wire/"): z.read(n) for n in names if n.startswith("flowclip/wire/")}
        metadata = z.read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    assert wire == _flatc_wire(tmp_path)
    assert {n.removeprefix("flowclip/") for n in names if re.fullmatch(r"flowclip/[^/]+\.py", n)} == MODULES
    assert not [n for n in names if "__pycache__" in n or n.startswith(("proto/", "tests/", "clients/"))], names
    assert re.search(rf"^Version: {re.escape(flowclip.__version__)}$", metadata, re.M), metadata
    assert "Requires-Dist: flatbuffers>=" in metadata and "Requires-Python: >=3.11" in metadata, metadata


def test_the_wheel_installs_into_a_fresh_venv(wheel, tmp_path):
    python = _fresh_venv(tmp_path / "venv")
    _pip(python, "install", "--no-index", "--no-deps", str(wheel))
    _pip(python, "check")  # the dependencies, met by the test venv's packages
    found = _inspect(python, tmp_path)
    site = str((tmp_path / "venv").resolve())
    assert found["file"].startswith(site) and found["wire"].startswith(site), found
    assert found["spec"] == str(Path(found["file"]).parent / "openapi.yaml"), found
    assert found["version"] == flowclip.__version__
    assert found["operations"] == _repo_operations()
    assert found["identifier"] == "FCW1"


def test_an_sdist_carries_proto_and_builds_on_its_own(source_copy, tmp_path):
    build = ("import sys; from setuptools import build_meta; print(build_meta.build_sdist(sys.argv[1]))")
    run = subprocess.run([sys.executable, "-c", build, str(tmp_path)], cwd=source_copy / "clients" / "python",
                         capture_output=True, text=True, timeout=BUILD_TIMEOUT, env=_env())
    assert run.returncode == 0, run.stderr
    sdist = tmp_path / run.stdout.split()[-1]
    top = f"flowclip-{flowclip.__version__}"
    with tarfile.open(sdist) as t:
        names = set(t.getnames())
        assert t.extractfile(f"{top}/proto/openapi.yaml").read() == (PROTO / "openapi.yaml").read_bytes()
    assert f"{top}/proto/flowclip.fbs" in names and f"{top}/setup.py" in names
    assert not [n for n in names if "/flowclip/wire" in n or n == f"{top}/flowclip/openapi.yaml"], names
    # pip unpacks it away from any checkout: the build reads the sdist's own proto/.
    _pip(sys.executable, "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-w", str(tmp_path / "dist"),
         str(sdist), cwd=tmp_path)
    (built,) = (tmp_path / "dist").glob("flowclip-*.whl")
    with zipfile.ZipFile(built) as z:
        assert z.read("flowclip/openapi.yaml") == (PROTO / "openapi.yaml").read_bytes()
        assert "flowclip/wire/Envelope.py" in z.namelist()


def test_an_editable_install_generates_beside_the_sources(source_copy, tmp_path):
    sources = source_copy / "clients" / "python"
    python = _fresh_venv(tmp_path / "venv")
    _pip(python, "install", "--no-index", "--no-deps", "--no-build-isolation", "-e", str(sources))
    found = _inspect(python, tmp_path)
    assert Path(found["file"]) == sources / "flowclip" / "__init__.py", found
    assert Path(found["spec"]).read_bytes() == (PROTO / "openapi.yaml").read_bytes()
    assert Path(found["wire"]).parent == sources / "flowclip" / "wire", found
    assert found["operations"] == _repo_operations()
