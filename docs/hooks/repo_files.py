"""MkDocs hook: publish the repository's own reference pages and benchmark
reports inside the documentation site, and keep every relative link working.

Some pages live beside what they describe rather than under docs/: the scene
file reference (scenes/README.md), the template database (templates/README.md),
the wire contracts (proto/), the editor's npm scripts (web/README.md), the
Python client (clients/python/README.md), and the reports the benchmarks write
(bench/).
They stay where they are, so that the tools that write them and a reader on a
code host find them there; this hook adds them to the site at the same path
(bench/cache/cache.md is served as bench/cache/cache.html), and rewrites the
relative links of every page, written as they resolve in the repository
(`../bench/cache/cache.md` from docs/cache.md), to where the target is in the
site. A link to a repository file the site does not carry (a source file) is
turned into plain text, so that `mkdocs build --strict` only fails on links
that are broken in the repository as well.
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[2]

# Repository paths published in the site (globs relative to the root).
MIRRORED = [
    "scenes/README.md",
    "templates/README.md",
    "proto/README.md",
    "proto/openapi.yaml",
    "proto/flowclip.fbs",
    "web/README.md",
    "clients/python/README.md",
    "bench/**/*.md",
    "bench/**/*.json",
    "bench/**/*.csv",
    "bench/**/*.svg",
]

LINK = re.compile(r"(!?)\[([^\]\n]*)\]\(([^)\s]+)\)")
FENCE = re.compile(r"^(```|~~~)")


def _mirrored_paths() -> set[str]:
    paths: set[str] = set()
    for pattern in MIRRORED:
        for p in ROOT.glob(pattern):
            if p.is_file():
                paths.add(p.relative_to(ROOT).as_posix())
    return paths


def on_files(files: Files, config) -> Files:
    for path in sorted(_mirrored_paths()):
        files.append(File(path, str(ROOT), config["site_dir"], config["use_directory_urls"]))
    return files


def _repo_path(page_file: File, docs_dir: Path) -> str:
    """Where the page's source lives in the repository."""
    src = Path(page_file.abs_src_path).resolve()
    return src.relative_to(ROOT).as_posix()


def _site_target(repo_target: str, mirrored: set[str], docs_prefix: str) -> str | None:
    if repo_target.startswith(docs_prefix):
        return repo_target[len(docs_prefix):]
    if repo_target in mirrored:
        return repo_target
    # A folder whose files are published (bench/accuracy/): its report, if any.
    folder = repo_target.rstrip("/")
    for candidate in (f"{folder}/README.md", f"{folder}/{posixpath.basename(folder)}.md"):
        if candidate in mirrored:
            return candidate
    return None


def on_page_markdown(markdown: str, page, config, files: Files) -> str:
    docs_dir = Path(config["docs_dir"]).resolve()
    docs_prefix = docs_dir.relative_to(ROOT).as_posix() + "/"
    mirrored = _mirrored_paths()
    page_repo = _repo_path(page.file, docs_dir)
    page_site_dir = posixpath.dirname(page.file.src_uri)

    def rewrite(match: re.Match) -> str:
        bang, text, target = match.groups()
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith(("#", "/")):
            return match.group(0)
        path, sep, fragment = target.partition("#")
        if not path:
            return match.group(0)
        repo_target = posixpath.normpath(posixpath.join(posixpath.dirname(page_repo), path))
        if path.endswith("/"):
            repo_target += "/"
        site = _site_target(repo_target, mirrored, docs_prefix)
        if site is None:
            return text if not bang else match.group(0)
        new = posixpath.relpath(site, page_site_dir or ".")
        return f"{bang}[{text}]({new}{sep}{fragment})"

    out, in_fence = [], False
    for line in markdown.split("\n"):
        if FENCE.match(line.lstrip()):
            in_fence = not in_fence
        out.append(line if in_fence else LINK.sub(rewrite, line))
    return "\n".join(out)
