#!/usr/bin/env python3
"""Writes the text seed corpora of fuzz_rest_request and fuzz_scene_parser
(server/fuzz/corpus/<target>/), including the regression inputs (regress-*)
of known bugs. The scene seeds copied from scenes/ and server/tests/bad_scenes
are not written here (cp). Usage, from the repository root:

    python3 server/fuzz/make_text_seeds.py

A REST input is METHOD SP TARGET LF, headers (name: value LF), LF, body
(fuzz_rest_request.cpp). The fuzz fixture has the scene `tiny`, the template
`tiny`, the session `fuzz` with the instance `drop`.
"""

from pathlib import Path

HERE = Path(__file__).resolve().parent
CORPUS = HERE / "corpus"

JSON = "content-type: application/json\n"


def rest(method, target, body=b"", headers=""):
    if isinstance(body, str):
        body = body.encode()
    head = f"{method} {target}\n"
    if headers or body:
        head += headers + "\n"
    return head.encode("latin-1") + body


REST = {
    # valid requests, one per route
    "health": rest("GET", "/api/health"),
    "head-health": rest("HEAD", "/api/health"),
    "parameters-3d": rest("GET", "/api/parameters?dimension=3"),
    "presets": rest("GET", "/api/presets"),
    "templates": rest("GET", "/api/templates"),
    "template": rest("GET", "/api/templates/tiny"),
    "template-preview": rest("GET", "/api/templates/tiny/preview?frame=2&max=10"),
    "template-delete": rest("DELETE", "/api/templates/tiny"),
    "scenes": rest("GET", "/api/scenes"),
    "scene": rest("GET", "/api/scenes/tiny"),
    "scene-save": rest("POST", "/api/scenes", '{"name": "saved", "session": "fuzz", "force": true}', JSON),
    "sessions": rest("GET", "/api/sessions"),
    "session-create": rest("POST", "/api/sessions",
                           '{"scene": "tiny", "name": "second", "history_cap_mb": 1, "playback_speed": 30, "threads": 1}',
                           JSON),
    "session": rest("GET", "/api/sessions/fuzz"),
    "session-delete": rest("DELETE", "/api/sessions/fuzz"),
    "session-stats": rest("GET", "/api/sessions/fuzz/stats"),
    "session-scene": rest("GET", "/api/sessions/fuzz/scene"),
    "session-record-template": rest("POST", "/api/sessions/fuzz/templates",
                                    '{"name": "rec", "region_min": [0, 0], "region_max": [0.2, 0.1], '
                                    '"first_frame": 0, "last_frame": 0, "force": true}', JSON),
    "instances": rest("GET", "/api/sessions/fuzz/instances"),
    "instance": rest("GET", "/api/sessions/fuzz/instances/drop"),
    "instance-add": rest("POST", "/api/sessions/fuzz/instances",
                         '{"name": "drop2", "template": "tiny", "start": 0.1, "reverse": true, '
                         '"transform": [{"time": 0, "translation": [0.05, 0.02]}, '
                         '{"time": 1, "translation": [0.1, 0.02], "rotation": 30, "scale": 1.5}]}', JSON),
    "instance-patch": rest("PATCH", "/api/sessions/fuzz/instances/drop", '{"start": 0.3, "speed": 2, "crop_end": null}',
                           JSON),
    "instance-delete": rest("DELETE", "/api/sessions/fuzz/instances/drop"),
    "settings-patch": rest("PATCH", "/api/sessions/fuzz/settings",
                           '{"settings": {"frame_rate": 30}, "solver": {"density_tolerance_pct": 0.1}, '
                           '"control": {"forces_every_substep": true}}', JSON),
    "edit": rest("GET", "/api/sessions/fuzz/edits/1"),
    "transport-step": rest("POST", "/api/sessions/fuzz/transport", '{"command": "step", "frames": 2}', JSON),
    "transport-play": rest("POST", "/api/sessions/fuzz/transport", '{"command": "play"}', JSON),
    "transport-pause": rest("POST", "/api/sessions/fuzz/transport", '{"command": "pause"}', JSON),
    "transport-reset": rest("POST", "/api/sessions/fuzz/transport", '{"command": "reset"}', JSON),
    "transport-seek": rest("POST", "/api/sessions/fuzz/transport", '{"command": "seek", "frame": 0}', JSON),
    "transport-speed": rest("POST", "/api/sessions/fuzz/transport", '{"command": "speed", "speed": 24}', JSON),
    "frame-json": rest("GET", "/api/sessions/fuzz/frames/0"),
    "frame-binary": rest("GET", "/api/sessions/fuzz/frames/latest?format=binary"),
    "frame-accept": rest("GET", "/api/sessions/fuzz/frames/latest", headers="accept: application/x-flowclip-frame\n"),
    "export": rest("POST", "/api/sessions/fuzz/export", '{"name": "out", "first_frame": 0, "last_frame": 0, "force": true}',
                   JSON),
    "export-get": rest("GET", "/api/exports/out.xdmf"),
    # errors the API answers by design
    "method-not-allowed": rest("PUT", "/api/sessions/fuzz"),
    "no-endpoint": rest("GET", "/api/nothing/here"),
    "bad-json": rest("POST", "/api/sessions", '{"scene": ', JSON),
    "bad-name": rest("GET", "/api/templates/..%2F..%2Fetc"),
    # known bugs (docs/fuzzing.md, "Regression inputs")
    "regress-scene-name-ff": rest("GET", "/api/scenes/%ff"),
    "regress-template-name-overlong-dot": rest("GET", "/api/templates/%c0%ae"),
    "regress-template-preview-ff": rest("GET", "/api/templates/%ff/preview"),
    "regress-export-name-ff": rest("GET", "/api/exports/%ff.h5"),
    "regress-session-id-ff": rest("GET", "/api/sessions/%ff"),
    "regress-session-delete-ff": rest("DELETE", "/api/sessions/%ff"),
    "regress-session-scene-invalid-utf8": rest("POST", "/api/sessions", b'{"scene":"dr\xffop"}', JSON),
    "regress-number-overflow-session": rest("POST", "/api/sessions", '{"scene": "tiny", "playback_speed": 1e999}', JSON),
    "regress-number-overflow-transport": rest("POST", "/api/sessions/fuzz/transport",
                                              '{"command": "speed", "speed": 1e999}', JSON),
    "regress-number-overflow-instance": rest("PATCH", "/api/sessions/fuzz/instances/drop", '{"start": 1e999}', JSON),
    "regress-deep-nesting-inline-scene": rest("POST", "/api/sessions",
                                              '{"scene": {"dimension": 2, "x": ' + "[" * 100000 + "]" * 100000 + "}}", JSON),
    "regress-deep-nesting-body": rest("POST", "/api/sessions/fuzz/instances", "[" * 100000, JSON),
    "regress-instance-name-invalid-utf8-patch": rest("PATCH", "/api/sessions/fuzz/instances/dr%ffop",
                                                     '{"start": 0.5}', JSON),
    "regress-instance-name-invalid-utf8-get": rest("GET", "/api/sessions/fuzz/instances/%ff"),
    "regress-instance-name-invalid-utf8-delete": rest("DELETE", "/api/sessions/fuzz/instances/dr%ffop"),
    "regress-instance-add-invalid-utf8": rest("POST", "/api/sessions/fuzz/instances",
                                              b'{"name": "dr\xffop", "template": "tiny"}', JSON),
    "regress-method-invalid-utf8": rest("G\xff\xfeT", "/api/sessions/fuzz"),
    "regress-path-invalid-utf8-404": rest("GET", "/api/%ff%fe/x"),
}

SCENE = {
    # known bugs: nesting that exhausted the stack, an overflowing number,
    # invalid UTF-8 in a name
    "regress-deep-nesting-array": b"[" * 100000,
    "regress-deep-nesting-balanced": b"[" * 100000 + b"]" * 100000,
    "regress-deep-nesting-object": b'{"a":' * 50000 + b"1" + b"}" * 50000,
    "regress-deep-nesting-in-scene": b'{"dimension": 2, "name": ' + b"[" * 100000 + b"]" * 100000 + b"}",
    "regress-number-overflow": b'{"name": "big", "dimension": 2, "particle_radius": 1e999, '
                               b'"domain": {"min": [0, 0], "max": [1, 1]}, "fluid_blocks": [{"min": [0, 0], "max": [0.5, 0.5]}]}',
    "regress-invalid-utf8-name": b'{"name": "dr\xffop", "dimension": 2, "particle_radius": 0.01, '
                                 b'"domain": {"min": [0, 0], "max": [1, 1]}, "fluid_blocks": [{"min": [0, 0], "max": [0.5, 0.5]}]}',
}


def write(target, items):
    out = CORPUS / target
    out.mkdir(parents=True, exist_ok=True)
    for name, data in items.items():
        if isinstance(data, str):
            data = data.encode("latin-1")
        (out / name).write_bytes(data)
    print(f"{len(items)} seeds in {out}")


if __name__ == "__main__":
    write("rest_request", REST)
    write("scene_parser", SCENE)
