"""The repository speaks to users: no tracked text names an internal issue by its number."""

from __future__ import annotations

import re
import subprocess

from repo_paths import ROOT

ISSUE = re.compile(r"\b[Ii]ssues?\s*#?\d+\b|\(#\d+\)")
TEXT = (".md", ".py", ".cpp", ".h", ".ts", ".mjs", ".yaml", ".yml", ".json", ".fbs", ".txt", ".sh", ".css", ".html")
NAMES = ("Makefile", "Dockerfile", "CMakeLists.txt")


def tracked_text_files():
    out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    for rel in out.splitlines():
        path = ROOT / rel
        if (rel.endswith(TEXT) or path.name in NAMES) and "package-lock" not in rel and path.is_file():
            yield rel, path


def test_no_internal_issue_numbers():
    found = []
    for rel, path in tracked_text_files():
        for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            m = ISSUE.search(line)
            if m:
                found.append(f"{rel}:{n}: {m.group(0)!r} in {line.strip()[:100]}")
    assert not found, "internal issue numbers in tracked text:\n" + "\n".join(found[:30])


def test_the_pattern_catches_what_it_must():
    # Built here, so that this file holds no such text itself.
    for word, number in (("see issue", " 5"), ("Issue", " #23 says"), ("the cache (", "#23)"), ("issues", " 24")):
        text = word + number
        assert ISSUE.search(text), text
    for text in ("colour #73b3ff", "session s5", "frame 23", "a[#1]", "&#39;", "tissue 3"):
        assert not ISSUE.search(text), text
