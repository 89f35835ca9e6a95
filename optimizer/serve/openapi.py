"""The OpenAPI 3.1 schema of ``shoha serve`` (``GET /openapi.json``), written out.

It describes every endpoint of docs/serve.md. The service validates bodies
itself (:mod:`optimizer.serve.bodies`); this schema is for the people and
generators on the other side, and tests/test_serve.py checks that every route
the app answers is in it.
"""

from __future__ import annotations

from functools import cache
from importlib import metadata
from typing import Any

from .bodies import MAX_BODY_BYTES, MAX_SESSION_BLOCKS

_NUM = {"type": "number"}
_VEC3 = {"type": "array", "items": _NUM, "minItems": 3, "maxItems": 3}
_UNITY3 = {"type": "object", "required": ["x", "y", "z"], "properties": {c: _NUM for c in "xyz"}}
_UNITYQ = {"type": "object", "required": ["x", "y", "z", "w"], "properties": {c: _NUM for c in "xyzw"}}
_ERROR = {"type": "object", "required": ["error"], "properties": {"error": {"type": "string"}}}


def _ref(name: str) -> dict[str, str]:
    return {"$ref": f"#/components/schemas/{name}"}


def _answer(description: str, schema: dict[str, Any] | None = None) -> dict[str, Any]:
    out: dict[str, Any] = {"description": description}
    if schema is not None:
        out["content"] = {"application/json": {"schema": schema}}
    return out


_ERRORS = {
    "400": _answer("the body is not JSON (malformed, NaN or Infinity, too deep)", _ref("Error")),
    "401": _answer("--token is set and the request lacks it", _ref("Error")),
    "404": _answer("no such session (ended, expired or never created) or block", _ref("Error")),
    "413": _answer(f"the body is larger than {MAX_BODY_BYTES} bytes", _ref("Error")),
    "415": _answer("the body is not sent as Content-Type: application/json", _ref("Error")),
    "422": _answer("the JSON is not what the endpoint takes; the session is unchanged", _ref("Error")),
}


def _op(summary: str, ok: dict[str, Any], *, body: dict[str, Any] | None = None,
        errors: tuple[str, ...] = ("401", "404")) -> dict[str, Any]:
    op: dict[str, Any] = {"summary": summary, "responses": {**ok, **{e: _ERRORS[e] for e in errors}}}
    if body is not None:
        op["requestBody"] = {"required": True, "content": {"application/json": {"schema": body}}}
    return op


_SID = {"name": "sid", "in": "path", "required": True, "schema": {"type": "string"}}
_BLOCK = {"name": "block", "in": "path", "required": True,
          "schema": {"type": "integer", "minimum": 0, "maximum": 2**53}}
_BODY_ERRORS = ("400", "401", "404", "413", "415", "422")


@cache
def schema() -> dict[str, Any]:
    """The schema, as a dict ready for JSON."""
    try:
        version = metadata.version("shoha")
    except metadata.PackageNotFoundError:  # pragma: no cover
        version = "unknown"
    state = _answer("the session's state", _ref("State"))
    return {
        "openapi": "3.1.0",
        "info": {"title": "shoha serve", "version": version,
                 "description": "Live checks of a trainee's block layout (docs/serve.md). World frame: "
                                "right-handed, z up, metres; Unity frame: left-handed, y up."},
        "paths": {
            "/healthz": {"get": _op("liveness", {"200": _answer("ok", {"type": "object"})},
                                    errors=("401",))},
            "/scenes": {"get": _op("the scenes served, with the keys of `shoha scene info --json`",
                                   {"200": _answer("scenes", {"type": "object"})}, errors=("401",))},
            "/sessions": {"post": _op("start a session", {"201": state}, body=_ref("NewSession"),
                                      errors=("400", "401", "413", "415", "422"))},
            "/sessions/{sid}": {
                "parameters": [_SID],
                "get": _op("the state", {"200": state}),
                "delete": _op("end the session", {"204": _answer("ended")}),
            },
            "/sessions/{sid}/blocks/{block}": {
                "parameters": [_SID, _BLOCK],
                "put": _op("lay or move a block", {"200": state}, body=_ref("Block"), errors=_BODY_ERRORS),
                "delete": _op("take a block out", {"200": state}),
            },
            "/sessions/{sid}/layout": {
                "parameters": [_SID],
                "put": _op("replace every block: a simulator save or a shoha-layout/1 object",
                           {"200": state}, body={"type": "object"}, errors=_BODY_ERRORS),
                "get": _op("the blocks as a shoha-layout/1 object (world frame)",
                           {"200": _answer("layout", {"type": "object"})}),
            },
            "/sessions/{sid}/score": {
                "parameters": [_SID],
                "post": _op("the object of `shoha score --json` for the blocks, settle included",
                            {"200": _answer("score", {"type": "object"}),
                             "409": _answer("the scene has no reference yet", _ref("Error"))}),
            },
            "/sessions/{sid}/hint": {
                "parameters": [_SID],
                "get": _op("the next block to lay, in the session's frame",
                           {"200": _answer("hint", _ref("Hint"))}),
            },
            "/sessions/{sid}/view": {
                "parameters": [_SID],
                "get": _op("an HTML page that shows the session live",
                           {"200": {"description": "page", "content": {"text/html": {}}}}),
            },
            "/sessions/{sid}/events": {
                "parameters": [_SID],
                "get": _op("WebSocket: the state after every change, with the blocks that changed "
                           "(`changed`, world frame), `removed` ids and `replaced`; the first event "
                           "holds every block", {"101": _answer("switching to WebSocket")}),
            },
            "/view": {"get": _op("a redirect to the view of the session started last, or a page that waits "
                                 "for one", {"200": {"description": "waiting page",
                                                     "content": {"text/html": {}}},
                                             "307": {"description": "to /sessions/{sid}/view"}},
                                 errors=("401",))},
            "/static/plotly.js": {"get": _op("plotly's bundle from the installed plotly package (the view)",
                                             {"200": {"description": "script",
                                                      "content": {"text/javascript": {}}}},
                                             errors=("401",))},
            "/openapi.json": {"get": _op("this schema", {"200": _answer("schema", {"type": "object"})},
                                         errors=("401",))},
        },
        "components": {"schemas": {
            "Error": _ERROR,
            "NewSession": {"type": "object", "required": ["scene"], "additionalProperties": False,
                           "properties": {"scene": {"type": "string"},
                                          "frame": {"enum": ["unity", "world"], "default": "unity"},
                                          "origin": {**_VEC3, "description": "Unity's origin in the world "
                                                                             "frame, metres"}}},
            "Block": {"oneOf": [
                {"title": "unity frame", "type": "object", "required": ["position", "rotation"],
                 "additionalProperties": False,
                 "properties": {"position": _UNITY3, "rotation": _UNITYQ, "type": {"type": "string"},
                                "time_s": {"type": "number", "minimum": 0}}},
                {"title": "world frame", "type": "object", "required": ["position", "quaternion"],
                 "additionalProperties": False,
                 "properties": {"position": _VEC3,
                                "quaternion": {"type": "array", "items": _NUM, "minItems": 4, "maxItems": 4,
                                               "description": "[w, x, y, z], unit"},
                                "type": {"type": "string"}, "time_s": {"type": "number", "minimum": 0}}},
            ]},
            "State": {"type": "object", "required": [
                "session", "porosity_percent", "blocks", "required_blocks", "remaining_blocks",
                "out_of_tolerance", "collisions", "protruding", "elapsed_s", "blocks_per_hour",
                "reference", "seconds"],
                "properties": {
                    "session": {"type": "string"}, "scene": {"type": "string"},
                    "frame": {"enum": ["unity", "world"]}, "version": {"type": "integer"},
                    "porosity_percent": _NUM,
                    "blocks": {"type": "integer", "maximum": MAX_SESSION_BLOCKS},
                    "required_blocks": {"type": "integer"}, "remaining_blocks": {"type": "integer"},
                    "out_of_tolerance": {"type": "array", "items": {
                        "type": "object", "properties": {"id": {"type": "integer"},
                                                         "outside_volume_m3": _NUM}}},
                    "collisions": {"type": "array", "items": {
                        "type": "object", "properties": {"a": {"type": "integer"}, "b": {"type": "integer"},
                                                         "depth_m": _NUM}}},
                    "protruding": {"type": "array", "items": {"type": "integer"}},
                    "unstable": {"type": "array", "items": {"type": "integer"}},
                    "elapsed_s": {"type": ["number", "null"]},
                    "blocks_per_hour": {"type": ["number", "null"]},
                    "reference": {"type": ["object", "null"], "properties": {
                        "porosity_percent": _NUM, "blocks": {"type": "integer"},
                        "source": {"type": "string"}}},
                    "seconds": _NUM,
                }},
            "Hint": {"type": "object", "required": ["block", "source", "status"], "properties": {
                "block": {"type": ["object", "null"]}, "source": {"enum": ["reference", "replan"]},
                "status": {"enum": ["ready", "pending", "unavailable", "complete"]},
                "plan_id": {"type": "integer"}, "message": {"type": "string"}, "seconds": _NUM}},
        }},
    }
