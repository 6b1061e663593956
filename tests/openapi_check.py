"""Validates REST responses against proto/openapi.yaml.

OpenApiChecker.observe is a flowclip.Client observer: every response
of the operation (method, path template) must have a status the spec lists
for it, and a JSON body must validate against that status's schema
(jsonschema, draft 2020-12, $refs resolved inside the spec). Error bodies
must also carry the HTTP status and its code. `exercised` collects the
operations seen.
"""

from __future__ import annotations

from pathlib import Path

import yaml
from jsonschema import Draft202012Validator
from referencing import Registry, Resource
from referencing.jsonschema import DRAFT202012

SPEC_PATH = Path(__file__).resolve().parent.parent / "proto" / "openapi.yaml"
BASE = "urn:flowclip:openapi"
METHODS = ("get", "put", "post", "delete", "patch", "head", "options")
ERROR_CODES = {400: "bad_request", 401: "unauthorized", 403: "forbidden", 404: "not_found",
               405: "method_not_allowed", 409: "conflict", 413: "payload_too_large", 422: "unprocessable",
               429: "too_many_sessions"}


def _pointer(*parts):
    return "/" + "/".join(str(p).replace("~", "~0").replace("/", "~1") for p in parts)


class OpenApiChecker:
    def __init__(self, path=SPEC_PATH):
        self.spec = yaml.safe_load(Path(path).read_text())
        self.registry = Registry().with_resource(BASE, Resource(contents=self.spec, specification=DRAFT202012))
        self.exercised = set()   # (METHOD, path template)
        self.checked = 0
        self._validators = {}

    def operations(self):
        return {(m.upper(), p) for p, item in self.spec["paths"].items() for m in item if m in METHODS}

    def _validator(self, pointer):
        if pointer not in self._validators:
            self._validators[pointer] = Draft202012Validator({"$ref": f"{BASE}#{pointer}"}, registry=self.registry)
        return self._validators[pointer]

    def _response(self, method, template, status):
        """(pointer of the response object, the object) for the documented status."""
        op = self.spec["paths"].get(template, {}).get(method.lower())
        if op is None and template in self.spec["paths"] and status == 405:
            return "/components/responses/MethodNotAllowed", self.spec["components"]["responses"]["MethodNotAllowed"]
        assert op is not None, f"{method} {template} is not in proto/openapi.yaml"
        assert str(status) in op["responses"], (
            f"{method} {template} answered {status}, which the spec does not list "
            f"({', '.join(op['responses'])})")
        pointer = _pointer("paths", template, method.lower(), "responses", str(status))
        response = op["responses"][str(status)]
        while "$ref" in response:
            pointer = response["$ref"][1:]
            response = self.registry.resolver(BASE).lookup(f"{BASE}#{pointer}").contents
        return pointer, response

    def check(self, method, template, status, content_type, body):
        """Raises AssertionError (or jsonschema.ValidationError) when the response breaks the spec."""
        self.exercised.add((method.upper(), template))
        pointer, response = self._response(method, template, status)
        content = response.get("content", {})
        media = (content_type or "").split(";")[0].strip()
        if not content:
            return
        assert media in content, f"{method} {template} {status}: content type {media!r}, spec has {list(content)}"
        if media != "application/json":
            return
        assert isinstance(body, (dict, list)), f"{method} {template} {status}: body is not JSON"
        self._validator(pointer + "/content/" + media.replace("/", "~1") + "/schema").validate(body)
        self.checked += 1
        if status >= 400:
            assert body["error"]["status"] == status, f"error.status {body['error']['status']} != HTTP {status}"
            if status in ERROR_CODES:
                assert body["error"]["code"] == ERROR_CODES[status], body

    def observe(self, method, template, response):
        """flowclip.Client observer."""
        body = None
        if response.headers.get("Content-Type", "").startswith("application/json"):
            body = response.json()
        self.check(method, template, response.status_code, response.headers.get("Content-Type"), body)
