"""Build step of the flowclip package: its REST contract and wire code come from proto/.

Nothing of proto/ is kept in git under clients/python. When the package is built
(pip install, pip wheel), build_py

  * copies proto/openapi.yaml to flowclip/openapi.yaml (the operations table and
    __version__ are read from it at import), and
  * runs `flatc --python -I proto -o TMP proto/*.fbs` (the schemas and include
    path server/CMakeLists.txt compiles for C++ and TypeScript) and puts the
    namespace flowclip.wire it generates in flowclip/wire.

proto/ is $FLOWCLIP_PROTO_DIR if set, else ./proto (an sdist carries a copy), else
../../proto (the repository). flatc is $FLATC, else `flatc` on PATH (Debian's
flatbuffers-compiler, flatc 2.0.8). The package version is info.version of openapi.yaml.

A regular install writes both into the build directory only. An editable install
(pip install -e) writes them beside the sources (git-ignored): run it again after
changing proto/.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.command.sdist import sdist

HERE = Path(__file__).resolve().parent
PACKAGE = "flowclip"
SPEC = "openapi.yaml"


def proto_dir() -> Path:
    if os.environ.get("FLOWCLIP_PROTO_DIR"):
        candidates = [Path(os.environ["FLOWCLIP_PROTO_DIR"])]
    else:
        candidates = [HERE / "proto", HERE.parent.parent / "proto"]
    for d in candidates:
        if (d / SPEC).is_file() and any(d.glob("*.fbs")):
            return d.resolve()
    raise SystemExit(f"flowclip: {SPEC} and *.fbs not found in {' or '.join(map(str, candidates))}; "
                     "build from a FlowClip checkout (pip install clients/python) or set FLOWCLIP_PROTO_DIR")


def spec_version(spec: Path) -> str:
    """info.version of the OpenAPI document (read by hand: PyYAML is not a build requirement)."""
    in_info = False
    for line in spec.read_text().splitlines():
        if re.match(r"\S", line):
            in_info = line.startswith("info:")
        elif in_info and (m := re.match(r"\s+version:\s*['\"]?([^'\"#\s]+)", line)):
            return m.group(1)
    raise SystemExit(f"flowclip: no info.version in {spec}")


def generate(package_dir: Path) -> list[Path]:
    """openapi.yaml and the flatc-generated wire code into package_dir; returns the files written."""
    proto = proto_dir()
    flatc = os.environ.get("FLATC") or shutil.which("flatc")
    if not flatc:
        raise SystemExit("flowclip: flatc not found: install flatbuffers-compiler (flatc 2.0.8) or set FLATC")
    package_dir.mkdir(parents=True, exist_ok=True)
    written = [package_dir / SPEC]
    shutil.copyfile(proto / SPEC, written[0])
    with tempfile.TemporaryDirectory(prefix="flowclip-flatc-") as tmp:
        schemas = sorted(str(p) for p in proto.glob("*.fbs"))
        subprocess.run([flatc, "--python", "-I", str(proto), "-o", tmp, *schemas], check=True)
        out = Path(tmp)
        foreign = [p.name for p in out.iterdir() if p.name != PACKAGE]
        if foreign:
            raise SystemExit(f"flowclip: the schemas declare namespaces outside {PACKAGE}.*: {foreign}")
        for sub in sorted(p for p in (out / PACKAGE).iterdir() if p.is_dir()):
            target = package_dir / sub.name
            shutil.rmtree(target, ignore_errors=True)  # no module of a removed table survives
            shutil.copytree(sub, target)
            written += sorted(target.rglob("*.py"))
    return written


class BuildPy(build_py):
    def run(self):
        if not self.editable_mode:
            # pip builds in place: a module removed from the sources must not linger in the wheel.
            shutil.rmtree(Path(self.build_lib) / PACKAGE, ignore_errors=True)
        super().run()
        target = HERE / PACKAGE if self.editable_mode else Path(self.build_lib) / PACKAGE
        self._generated = [str(p) for p in generate(target)]

    def get_outputs(self, include_bytecode=True):
        return super().get_outputs(include_bytecode) + getattr(self, "_generated", [])


class Sdist(sdist):
    def make_release_tree(self, base_dir, files):
        super().make_release_tree(base_dir, files)
        # The sdist builds on its own: it carries the proto files build_py reads.
        proto, out = proto_dir(), Path(base_dir) / "proto"
        out.mkdir(exist_ok=True)
        for f in [proto / SPEC, *sorted(proto.glob("*.fbs"))]:
            shutil.copyfile(f, out / f.name)


setup(version=spec_version(proto_dir() / SPEC), cmdclass={"build_py": BuildPy, "sdist": Sdist})
