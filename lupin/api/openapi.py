"""The OpenAPI 3.1 document, generated from the route table and the pydantic models.

Nothing here is written by hand that the code already knows: paths, methods,
bodies and responses come from :data:`lupin.api.routes.ROUTES`, schemas from
the models (``model_json_schema`` with ``#/components/schemas/{model}`` refs).
The live document also lists this robot's joint and preset names as enums, so
a client generated from it knows what exists. The WebSocket frames are in
``components.schemas`` too, named in the ``/api/ws`` operation.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel
from pydantic.json_schema import JsonSchemaMode, models_json_schema

from lupin import __version__
from lupin import api_models as m
from lupin.api import frames
from lupin.api.routes import POSE_NAME, ROUTES, Route

REF = "#/components/schemas/{model}"
ERROR_TEXT = {
    400: "Invalid body, field or name; the message names the field",
    401: "A token is configured and the request did not carry it",
    403: "Refused: the request came from a page of another origin",
    404: "Unknown joint, source, preset or pose",
    409: "Refused by the robot's state (torque off, E-stop engaged, not seeded, too far)",
    413: "Body larger than api.max_body_bytes",
    415: "The body is not application/json",
    503: "The servo bus is down",
}
WS_DESCRIPTION = """WebSocket. The server sends `hello` (robot info) then `state` frames at
`api.state_hz`. The client sends `twist` frames (no reply unless they carry an `id`) and
commands with an `id` (`estop`, `joint`, `gripper`, `torque`, `init`, `preset`, `pose_go`,
`heal`), answered by a `reply` frame. With a token, offer the subprotocols
`["lupin.v1", "bearer.<token>"]` or send `{"type": "auth", "token": ...}` first.
Frame schemas: components.schemas `*Frame`."""
# OpenAPI links: a response that names a resource another operation takes by name.
# A taught pose is the API's one created resource: teaching it (PUT) answers its name,
# which reads, goes to and forgets it. Clients, and schemathesis' stateful run (the
# reliability suite), follow these to chain calls: teach, read, go, forget, read again.
POSE_LINKS = {
    "GetPose": "get_pose",
    "GoToPose": "go_pose",
    "DeletePose": "delete_pose",
}
LINKS: dict[str, dict[str, str]] = {"save_pose": POSE_LINKS, "get_pose": POSE_LINKS}


def _json(schema: dict[str, Any], description: str) -> dict[str, Any]:
    return {"description": description, "content": {"application/json": {"schema": schema}}}


def _schemas() -> tuple[dict[tuple[type[BaseModel], JsonSchemaMode], Any], dict[str, Any]]:
    wanted: list[tuple[type[BaseModel], JsonSchemaMode]] = [(m.ErrorResponse, "serialization")]
    for route in ROUTES:
        if route.request is not None:
            wanted.append((route.request, "validation"))
        wanted.append((route.response, "serialization"))
    for model in frames.FRAME_MODELS:
        mode: JsonSchemaMode = "validation" if issubclass(model, m.Request) else "serialization"
        wanted.append((model, mode))
    unique = list(dict.fromkeys(wanted))
    refs, top = models_json_schema(unique, ref_template=REF)
    by_model: dict[tuple[type[BaseModel], JsonSchemaMode], Any] = {}
    for (kind, mode), ref in refs.items():
        if isinstance(kind, type) and issubclass(kind, BaseModel):
            by_model[(kind, mode)] = ref
    return by_model, dict(top.get("$defs", {}))


def _parameters(route: Route, robot: m.RobotInfo | None) -> list[dict[str, Any]]:
    out = []
    for name in ("joint", "preset", "pose"):
        if "{" + name + "}" not in route.path:
            continue
        schema: dict[str, Any] = {"type": "string"}
        if name == "joint" and robot is not None:
            schema["enum"] = [j.name for j in robot.joints]
        elif name == "preset" and robot is not None:
            schema["enum"] = sorted(robot.presets)
        elif name == "pose":
            schema["pattern"] = POSE_NAME.pattern
        out.append({"name": name, "in": "path", "required": True, "schema": schema})
    return out


def _operation(
    route: Route,
    refs: dict[tuple[type[BaseModel], JsonSchemaMode], Any],
    robot: m.RobotInfo | None,
    token_required: bool,
) -> dict[str, Any]:
    error_ref = refs[(m.ErrorResponse, "serialization")]
    op: dict[str, Any] = {
        "operationId": route.call.__name__.lstrip("_"),
        "summary": route.summary,
        "tags": [route.tag],
        "responses": {"200": _json(refs[(route.response, "serialization")], route.summary)},
    }
    links = LINKS.get(op["operationId"], {})
    if links:
        op["responses"]["200"]["links"] = {
            name: {"operationId": target, "parameters": {"pose": "$response.body#/name"}}
            for name, target in links.items()
            if target != op["operationId"]
        }
    params = _parameters(route, robot)
    if params:
        op["parameters"] = params
    if route.request is not None:
        op["requestBody"] = {
            "required": route.body_required,
            "content": {"application/json": {"schema": refs[(route.request, "validation")]}},
        }
    for status in route.error_statuses():
        op["responses"][str(status)] = _json(error_ref, ERROR_TEXT.get(status, "Refused"))
    if route.mutating and token_required:
        op["security"] = [{"bearerAuth": []}]
    return op


def _extra_paths(error_ref: dict[str, Any], token_required: bool) -> dict[str, Any]:
    text = {"type": "string"}
    ws: dict[str, Any] = {
        "operationId": "websocket",
        "summary": "State push and commands over one WebSocket",
        "description": WS_DESCRIPTION,
        "tags": ["websocket"],
        "responses": {
            "101": {"description": "Switching protocols: the WebSocket is open"},
            "400": _json(error_ref, "Not a WebSocket upgrade"),
            "401": _json(error_ref, "Wrong token offered at upgrade"),
            "403": _json(error_ref, "Upgrade from a page of another origin"),
        },
        "x-lupin-frames": {
            "client": [
                f"#/components/schemas/{c.__name__}"
                for c in frames.FRAME_MODELS
                if issubclass(c, m.Request)
            ],
            "server": [
                f"#/components/schemas/{c.__name__}"
                for c in frames.FRAME_MODELS
                if not issubclass(c, m.Request)
            ],
        },
    }
    if token_required:
        ws["security"] = [{"bearerAuth": []}]
    return {
        "/api/openapi.json": {
            "get": {
                "operationId": "openapi",
                "summary": "This document",
                "tags": ["meta"],
                "responses": {"200": _json({"type": "object"}, "The OpenAPI 3.1 document")},
            }
        },
        "/metrics": {
            "get": {
                "operationId": "metrics",
                "summary": "Prometheus text exposition",
                "tags": ["meta"],
                "responses": {
                    "200": {
                        "description": "Prometheus text format 0.0.4",
                        "content": {"text/plain": {"schema": text}},
                    }
                },
            }
        },
        "/api/ws": {"get": ws},
        "/": {
            "get": {
                "operationId": "hmi",
                "summary": "The browser HMI",
                "tags": ["hmi"],
                "responses": {
                    "200": {"description": "index.html", "content": {"text/html": {"schema": text}}}
                },
            }
        },
        "/static/{file}": {
            "get": {
                "operationId": "hmi_static",
                "summary": "The HMI's static files",
                "tags": ["hmi"],
                "parameters": [
                    {"name": "file", "in": "path", "required": True, "schema": {"type": "string"}}
                ],
                "responses": {
                    "200": {"description": "The file", "content": {"*/*": {}}},
                    "404": _json(error_ref, "No such file"),
                },
            }
        },
    }


def build_document(robot: m.RobotInfo | None, *, token_required: bool) -> dict[str, Any]:
    refs, schemas = _schemas()
    paths: dict[str, dict[str, Any]] = {}
    for route in ROUTES:
        op = _operation(route, refs, robot, token_required)
        paths.setdefault(route.path, {})[route.method.lower()] = op
    paths.update(_extra_paths(refs[(m.ErrorResponse, "serialization")], token_required))
    title = "Lupin robot daemon API"
    return {
        "openapi": "3.1.0",
        "info": {
            "title": title if robot is None else f"{title} ({robot.profile})",
            "version": __version__,
            "description": "SPEC §5. Angles are degrees unless the field name ends in _rad. "
            'Errors are {"error": {"code", "message"}}; nothing changes on an error.',
        },
        "paths": paths,
        "components": {
            "schemas": schemas,
            "securitySchemes": {"bearerAuth": {"type": "http", "scheme": "bearer"}},
        },
    }
