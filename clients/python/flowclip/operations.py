"""The REST contract the client speaks: openapi.yaml, packaged with it.

The build copies the repository's proto/openapi.yaml into the package
(clients/python/setup.py), so the operations table and the version come from
the installed package, never from a checkout.
"""

from __future__ import annotations

from pathlib import Path

import yaml

OPENAPI_SPEC = Path(__file__).resolve().with_name("openapi.yaml")
HTTP_METHODS = ("get", "put", "post", "delete", "patch", "head", "options")


def load_spec(spec_path=OPENAPI_SPEC) -> dict:
    """The OpenAPI document as a dict."""
    try:
        text = Path(spec_path).read_text()
    except FileNotFoundError:
        raise ImportError(f"{spec_path} is missing: install the package with pip "
                          "(pip install clients/python), which copies it from proto/") from None
    return yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))


def operations_of(spec: dict) -> dict:
    """operationId -> (METHOD, path template) of every operation of an OpenAPI document."""
    return {op["operationId"]: (method.upper(), path) for path, item in spec["paths"].items()
            for method, op in item.items() if method in HTTP_METHODS}


def load_operations(spec_path=OPENAPI_SPEC) -> dict:
    """operations_of the OpenAPI document at spec_path."""
    return operations_of(load_spec(spec_path))


SPEC = load_spec()
OPERATIONS = operations_of(SPEC)
VERSION = str(SPEC["info"]["version"])


def route(operation_id) -> tuple[str, str]:
    """(METHOD, path template) of an operation of the spec, by its operationId."""
    try:
        return OPERATIONS[operation_id]
    except KeyError:
        raise KeyError(f"{operation_id!r} is not an operationId of {OPENAPI_SPEC}") from None
