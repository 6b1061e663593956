"""One entry per paper: every citation key in the tracked sources and pages is
defined in docs/references.md, and every entry there is complete.

A key is written as the code writes it: `[` an upper-case letter and more
letters, an optional `*`, two digits, an optional lower-case letter, `]`
(Markdown may escape the star). An entry is a `### [KEY] Title { #anchor }`
heading followed by `- **Field:** value` lines (docs/references.md, "Keys").
"""

from __future__ import annotations

import re
import subprocess
from collections import Counter
from pathlib import Path

from repo_paths import ROOT

REFERENCES = "docs/references.md"
KEY = re.compile(r"\[([A-Z][A-Za-z]{0,7})(\\?\*)?(\d{2}[a-z]?)\]")
SOURCES = (".h", ".cpp", ".ts", ".mjs", ".py", ".md", ".cmake")
HEADING = re.compile(r"^### (?P<key>\[[^\]]+\])\s*(?P<title>.*?)\s*(?:\{[^}]*\})?\s*$")
FIELD = re.compile(r"^- \*\*(?P<name>[A-Za-z ]+):\*\*\s*(?P<value>.*)$")
DOI_LINK = re.compile(r"\[(10\.\d{4,9}/[^\]\s]+)\]\(https://doi\.org/\1\)")
NO_DOI = "no DOI"
REQUIRED = ("Authors", "Venue", "Year", "DOI", "Cited in")


def key_of(match: re.Match) -> str:
    return match.group(1) + ("*" if match.group(2) else "") + match.group(3)


def keys_in(text: str) -> set[str]:
    return {key_of(m) for m in KEY.finditer(text)}


def tracked_sources() -> dict[str, str]:
    out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    texts = {}
    for rel in out.splitlines():
        path = ROOT / rel
        if rel.endswith(SOURCES) and rel != REFERENCES and path.is_file():
            texts[rel] = path.read_text(encoding="utf-8", errors="replace")
    return texts


def parse_entries(text: str) -> list[dict]:
    """The entries in order, duplicates included: key, line, title, fields."""
    entries: list[dict] = []
    current, last = None, None
    for n, line in enumerate(text.splitlines(), 1):
        heading = HEADING.match(line)
        if heading:
            m = KEY.fullmatch(heading.group("key"))
            current = {"key": key_of(m) if m else heading.group("key"), "valid_key": m is not None, "line": n,
                       "title": heading.group("title"), "fields": {}}
            entries.append(current)
            last = None
        elif line.startswith("#"):
            current = None
        elif current is not None:
            field = FIELD.match(line)
            if field:
                last = field.group("name")
                current["fields"][last] = field.group("value").strip()
            elif last and line.startswith("  ") and line.strip():
                current["fields"][last] += " " + line.strip()
    return entries


def entry_problems(entries: list[dict], sources: dict[str, str]) -> list[str]:
    problems = []
    for key, count in Counter(e["key"] for e in entries).items():
        if count > 1:
            problems.append(f"[{key}] is defined {count} times")
    for e in entries:
        where = f"{REFERENCES}:{e['line']} [{e['key']}]"
        f = e["fields"]
        if not e["valid_key"]:
            problems.append(f"{where}: not a key of the code's form")
            continue
        if not e["title"]:
            problems.append(f"{where}: no title")
        for name in REQUIRED:
            if not f.get(name):
                problems.append(f"{where}: no {name}")
        year = f.get("Year", "")
        if year and not (re.fullmatch(r"\d{4}", year) and year[2:] == re.sub(r"\D", "", e["key"])):
            problems.append(f"{where}: year {year!r} does not match the key")
        doi = f.get("DOI", "")
        if doi and not (DOI_LINK.search(doi) or doi.startswith(NO_DOI)):
            problems.append(f"{where}: DOI is neither a https://doi.org/ link nor {NO_DOI!r}: {doi}")
        for path in re.findall(r"`([^`]+)`", f.get("Cited in", "")):
            if path not in sources:
                problems.append(f"{where}: cited in {path}, which is not a tracked source")
            elif e["key"] not in keys_in(sources[path]):
                problems.append(f"{where}: {path} does not cite it")
    return problems


def undefined_keys(sources: dict[str, str], defined: set[str]) -> list[str]:
    found = []
    for rel, text in sources.items():
        for n, line in enumerate(text.splitlines(), 1):
            for m in KEY.finditer(line):
                if key_of(m) not in defined:
                    found.append(f"{rel}:{n}: [{key_of(m)}] in {line.strip()[:100]}")
    return found


def test_every_cited_key_has_an_entry():
    entries = parse_entries((ROOT / REFERENCES).read_text(encoding="utf-8"))
    missing = undefined_keys(tracked_sources(), {e["key"] for e in entries})
    assert not missing, f"citation keys without an entry in {REFERENCES}:\n" + "\n".join(missing)


def test_every_entry_is_complete_and_defined_once():
    entries = parse_entries((ROOT / REFERENCES).read_text(encoding="utf-8"))
    assert len(entries) >= 10, f"{REFERENCES} lists {len(entries)} entries"
    problems = entry_problems(entries, tracked_sources())
    assert not problems, "\n".join(problems)


# The checks themselves, on text built here (so that this file holds no key
# that is not defined).
def test_a_new_key_without_an_entry_is_reported():
    new_key = "Xyz" + "99"
    sources = {"server/sph/new.cpp": f"// eq. (3) in [{new_key}]\nint a[10];\n", "docs/new.md": "[[AIA\\*12]](x)"}
    assert undefined_keys(sources, {"AIA*12"}) == [f"server/sph/new.cpp:1: [{new_key}] in // eq. (3) in [{new_key}]"]
    assert keys_in("a[i] x[2] [0] [D2] [v12] [ABC1]") == set()
    lettered = "Mon05" + "a"
    assert keys_in(f"[{lettered}] [AIA*12] [AIA\\*12] [SPDM20]") == {lettered, "AIA*12", "SPDM20"}


def test_incomplete_and_duplicate_entries_are_reported():
    k = "Ab" + "20"
    good = (f"### [{k}] A Title {{ #ab20 }}\n\n- **Authors:** A. Author, B. Buthor\n- **Venue:** Journal 1(2)\n"
            "- **Year:** 2020\n- **DOI:** [10.1000/xyz](https://doi.org/10.1000/xyz)\n- **Cited in:** `a.cpp`\n")
    sources = {"a.cpp": f"// [{k}]"}
    assert entry_problems(parse_entries(good), sources) == []
    no_doi = good.replace("[10.1000/xyz](https://doi.org/10.1000/xyz)", "10.1000/xyz")
    assert any("DOI" in p for p in entry_problems(parse_entries(no_doi), sources))
    assert entry_problems(parse_entries(no_doi.replace("10.1000/xyz", NO_DOI + " (a book)")), sources) == []
    no_venue = good.replace("- **Venue:** Journal 1(2)\n", "")
    assert any("no Venue" in p for p in entry_problems(parse_entries(no_venue), sources))
    wrong_year = good.replace("2020", "2021")
    assert any("year" in p for p in entry_problems(parse_entries(wrong_year), sources))
    assert any("defined 2 times" in p for p in entry_problems(parse_entries(good + "\n" + good), sources))
    assert any("does not cite" in p for p in entry_problems(parse_entries(good), {"a.cpp": "// nothing"}))


def test_the_references_page_is_in_the_site():
    assert Path(ROOT / REFERENCES).is_file()
    assert "references.md" in (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
