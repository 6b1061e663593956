"""The launcher of a portable install (server/launcher/main.cpp, docs/portable.md):
it runs the executable of the best x86-64 level this CPU has, next to itself,
with the same arguments and exit status; FLOWCLIP_CPU_LEVEL picks one by hand;
a missing or unusable level is a clear error, never a SIGILL.

The executables here are stand-ins that say which one ran, so that the choice
is checked on any machine; `make portable` checks the real ones' instructions.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from repo_paths import FLOWCLIP_BIN, ROOT

LAUNCHER = next((p for p in (FLOWCLIP_BIN.parent / "flowclip_launcher", ROOT / "build" / "flowclip_launcher")
                 if p.exists()), ROOT / "build" / "flowclip_launcher")


def cpu_flags() -> set[str]:
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("flags"):
            return set(line.split(":", 1)[1].split())
    return set()


FLAGS = cpu_flags()
HAS_V3 = {"avx2", "fma", "bmi2"} <= FLAGS
HAS_V4 = HAS_V3 and {"avx512f", "avx512bw", "avx512dq", "avx512vl"} <= FLAGS


def install(tmp_path: Path, levels: list[str]) -> Path:
    """A portable install: the launcher as `flowclip` beside stand-ins for the given levels."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    shutil.copy(LAUNCHER, bin_dir / "flowclip")
    for level in levels:
        exe = bin_dir / f"flowclip-{level}"
        exe.write_text(f'#!/bin/sh\necho "{level} $*"\nexit 7\n')
        exe.chmod(0o755)
    return bin_dir / "flowclip"


def run(launcher: Path, *args: str, level: str | None = None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "FLOWCLIP_CPU_LEVEL"}
    if level is not None:
        env["FLOWCLIP_CPU_LEVEL"] = level
    return subprocess.run([str(launcher), *args], capture_output=True, text=True, timeout=60, env=env)


pytestmark = pytest.mark.skipif(not HAS_V3, reason="this CPU is below x86-64-v3: nothing to launch")


def test_the_best_level_the_cpu_has_runs_with_the_arguments_and_its_exit_status(tmp_path):
    launcher = install(tmp_path, ["x86-64-v3", "x86-64-v4"])
    r = run(launcher, "run", "scenes/drop2d.json", "--frames", "3")
    assert r.returncode == 7, r.stderr
    best = "x86-64-v4" if HAS_V4 else "x86-64-v3"
    assert r.stdout.strip() == f"{best} run scenes/drop2d.json --frames 3"


def test_a_level_not_installed_falls_back_to_the_next(tmp_path):
    launcher = install(tmp_path, ["x86-64-v3"])
    r = run(launcher, "--version")
    assert r.returncode == 7 and r.stdout.strip() == "x86-64-v3 --version"


def test_the_level_can_be_chosen_by_hand(tmp_path):
    launcher = install(tmp_path, ["x86-64-v3", "x86-64-v4"])
    r = run(launcher, "bench", level="x86-64-v3")
    assert r.returncode == 7 and r.stdout.strip() == "x86-64-v3 bench"
    r = run(launcher, "bench", level="x86-64-v4")
    if HAS_V4:
        assert r.returncode == 7 and r.stdout.strip() == "x86-64-v4 bench"
    else:  # never a SIGILL: refused before running it
        assert r.returncode == 2 and "lacks its instructions" in r.stderr


def test_bad_choices_and_missing_executables_are_clear_errors(tmp_path):
    launcher = install(tmp_path, ["x86-64-v3"])
    r = run(launcher, level="pentium")
    assert r.returncode == 2 and "FLOWCLIP_CPU_LEVEL=pentium is not one of x86-64-v4, x86-64-v3" in r.stderr
    # v4 chosen by hand but only v3 installed (or a CPU without AVX-512): said, not crashed.
    r = run(launcher, level="x86-64-v4")
    assert r.returncode == 2
    assert ("cannot run" in r.stderr and "flowclip-x86-64-v4" in r.stderr) if HAS_V4 else \
        "lacks its instructions" in r.stderr
    empty = tmp_path / "empty"
    empty.mkdir()
    shutil.copy(LAUNCHER, empty / "flowclip")
    r = run(empty / "flowclip", "--version")
    assert r.returncode == 2 and "needs x86-64-v3 (AVX2, FMA, BMI2" in r.stderr and str(empty) in r.stderr


def test_the_launcher_itself_runs_on_any_x86_64(tmp_path):
    """Built for the x86-64 baseline: no AVX instruction, so that it can explain on an old CPU."""
    objdump = shutil.which("objdump")
    if objdump is None:
        pytest.skip("objdump (binutils) is missing")
    text = subprocess.run([objdump, "-d", "--no-show-raw-insn", str(LAUNCHER)], capture_output=True, text=True,
                          timeout=60).stdout
    assert "main" in text
    assert "%ymm" not in text and "%zmm" not in text
