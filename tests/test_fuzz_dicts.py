"""The fuzz dictionaries: valid libFuzzer lines, and parameter names only
from the declarations (make_fuzz_dict appends them), never a hand copy."""
import json
import pathlib
import re
import subprocess

from repo_paths import FLOWCLIP_BIN

ROOT = pathlib.Path(__file__).resolve().parent.parent
DICTS = sorted((ROOT / "server" / "fuzz").glob("*.dict"))
# libFuzzer's dictionary syntax: a comment, a blank line, or an optional
# name= then a double-quoted string (\\, \" and \xAB escapes).
LINE = re.compile(r'^(#.*|\s*|([A-Za-z_][A-Za-z0-9_]*=)?"([^"\\]|\\\\|\\"|\\x[0-9A-Fa-f]{2})*")$')


def declared_names():
    names = set()
    for d in (2, 3):
        ref = json.loads(subprocess.check_output([FLOWCLIP_BIN, "params", "--dimension", str(d)], timeout=120))
        for table in ("settings", "control", "instance"):
            names |= {row["name"] for row in ref[table]}
        for registry in ("solvers", "boundaries", "effects"):
            for method, entry in ref[registry].items():
                names.add(method)
                names |= {row["name"] for row in entry["params"]}
    return names


def test_every_line_is_libfuzzer_syntax():
    assert DICTS, "no dictionary under server/fuzz"
    bad = [f"{p.name}:{n}: {line}" for p in DICTS for n, line in enumerate(p.read_text().splitlines(), 1)
           if not LINE.match(line)]
    assert not bad, "lines libFuzzer would refuse:\n" + "\n".join(bad)


def test_hand_written_dictionaries_do_not_copy_declared_names():
    names = declared_names()
    assert {"density_tolerance_pct", "dfsph", "akinci2012", "attraction_weight"} <= names
    copied = []
    for p in DICTS:
        for line in p.read_text().splitlines():
            m = re.fullmatch(r'"\\"([A-Za-z0-9_]+)\\""', line)
            if m and m.group(1) in names:
                copied.append(f"{p.name}: {m.group(1)}")
    assert not copied, "declared names copied by hand (make_fuzz_dict prints them):\n" + "\n".join(copied)
