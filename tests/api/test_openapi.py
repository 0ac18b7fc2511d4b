"""The OpenAPI document is complete and true: every route is in it, and live answers match it."""

from __future__ import annotations

import re
from typing import Any

import aiohttp
import pytest
from jsonschema import Draft202012Validator

from lupin.api import ApiServer
from lupin.api.routes import ROUTES
from lupin.daemon import Daemon

from .conftest import TOKEN, start_api
from .helpers import call


async def fetch_doc(http: aiohttp.ClientSession, api: ApiServer) -> dict[str, Any]:
    async with http.get(api.url + "/api/openapi.json") as resp:
        assert resp.status == 200 and resp.content_type == "application/json"
        doc: dict[str, Any] = await resp.json()
        return doc


def schema_validator(doc: dict[str, Any], schema: dict[str, Any]) -> Draft202012Validator:
    """A validator for one schema of the document, its #/components refs resolvable."""
    root = {"components": doc["components"], **schema}
    return Draft202012Validator(root)


def check_response(doc: dict[str, Any], template: str, method: str, status: int, body: Any) -> None:
    op = doc["paths"][template][method.lower()]
    assert str(status) in op["responses"], f"{method} {template} answered undocumented {status}"
    schema = op["responses"][str(status)]["content"]["application/json"]["schema"]
    errors = list(schema_validator(doc, schema).iter_errors(body))
    assert not errors, f"{method} {template} {status}: {[e.message for e in errors]}"


async def test_document_lists_every_route(http: aiohttp.ClientSession, api: ApiServer) -> None:
    doc = await fetch_doc(http, api)
    assert doc["openapi"] == "3.1.0"
    registered = set()
    for route in api.app.router.routes():
        path = re.sub(r"\{(\w+):[^}]*\}", r"{\1}", route.resource.canonical)  # type: ignore[union-attr]
        registered.add((route.method.lower(), path))
    documented = {(m, p) for p, ops in doc["paths"].items() for m in ops}
    assert registered == documented
    for route in ROUTES:
        op = doc["paths"][route.path][route.method.lower()]
        assert op["responses"]["200"]["content"]["application/json"]["schema"] == {
            "$ref": f"#/components/schemas/{route.response.__name__}"
        }
        if route.request is not None:
            body = op["requestBody"]["content"]["application/json"]["schema"]
            assert body == {"$ref": f"#/components/schemas/{route.request.__name__}"}
        for status in route.error_statuses():
            assert op["responses"][str(status)]["content"]["application/json"]["schema"] == {
                "$ref": "#/components/schemas/ErrorResponse"
            }
        if route.mutating:
            assert {"400", "401", "403", "413", "415"} <= set(op["responses"])
    # This robot's names are in the live document.
    joint = doc["paths"]["/api/arm/joints/{joint}"]["post"]["parameters"][0]["schema"]
    assert "elbow_flex" in joint["enum"]
    assert "StateFrame" in doc["components"]["schemas"]


async def test_document_is_valid_openapi_31(http: aiohttp.ClientSession, api: ApiServer) -> None:
    validator = pytest.importorskip("openapi_spec_validator")
    validator.validate(await fetch_doc(http, api))


async def test_security_is_declared_only_with_a_token(
    http: aiohttp.ClientSession, api: ApiServer, daemon: Daemon
) -> None:
    open_doc = await fetch_doc(http, api)
    assert "security" not in open_doc["paths"]["/api/estop"]["post"]
    server = await start_api(daemon, token=TOKEN)
    try:
        doc = await fetch_doc(http, server)
    finally:
        await server.stop()
    assert doc["paths"]["/api/estop"]["post"]["security"] == [{"bearerAuth": []}]
    assert "security" not in doc["paths"]["/api/state"]["get"]


async def test_live_responses_match_the_document(
    http: aiohttp.ClientSession, api: ApiServer
) -> None:
    doc = await fetch_doc(http, api)
    # (method, template, concrete path, body): successes and refusals, in an order
    # that walks the robot through its states (torque off first, then on).
    steps: list[tuple[str, str, str, Any]] = [
        ("GET", "/api/health", "/api/health", None),
        ("GET", "/api/state", "/api/state", None),
        ("GET", "/api/robot", "/api/robot", None),
        ("GET", "/api/arm/presets", "/api/arm/presets", None),
        ("GET", "/api/arm/poses", "/api/arm/poses", None),
        ("POST", "/api/arm/joints/{joint}", "/api/arm/joints/elbow_flex", {"angle_deg": 5}),
        ("POST", "/api/arm/joints/{joint}", "/api/arm/joints/knee", {"angle_deg": 5}),
        ("POST", "/api/arm/joints/{joint}", "/api/arm/joints/elbow_flex", {"angle": 5}),
        ("POST", "/api/arm/init", "/api/arm/init", None),
        ("POST", "/api/base/twist", "/api/base/twist", {"source": "manual", "linear_x": 0.1}),
        ("POST", "/api/base/twist", "/api/base/twist", {"source": "joy"}),
        ("POST", "/api/arm/torque", "/api/arm/torque", {"enabled": True}),
        ("POST", "/api/arm/joints/{joint}", "/api/arm/joints/elbow_flex", {"angle_deg": 5}),
        ("POST", "/api/arm/gripper", "/api/arm/gripper", {"angle_deg": 5}),
        ("POST", "/api/arm/presets/{preset}", "/api/arm/presets/pick", None),
        ("POST", "/api/arm/presets/{preset}", "/api/arm/presets/nope", None),
        ("POST", "/api/arm/init", "/api/arm/init", None),
        ("PUT", "/api/arm/poses/{pose}", "/api/arm/poses/here", None),
        ("GET", "/api/arm/poses/{pose}", "/api/arm/poses/here", None),
        ("GET", "/api/arm/poses", "/api/arm/poses", None),
        ("POST", "/api/arm/poses/{pose}/go", "/api/arm/poses/here/go", {}),
        ("POST", "/api/arm/poses/{pose}/go", "/api/arm/poses/nope/go", {}),
        ("DELETE", "/api/arm/poses/{pose}", "/api/arm/poses/here", None),
        ("DELETE", "/api/arm/poses/{pose}", "/api/arm/poses/here", None),
        ("POST", "/api/heal", "/api/heal", None),
        ("POST", "/api/estop", "/api/estop", {"engaged": True}),
        ("POST", "/api/arm/torque", "/api/arm/torque", {"enabled": True}),
        ("GET", "/api/state", "/api/state", None),
        ("POST", "/api/estop", "/api/estop", {"engaged": False}),
    ]
    seen: set[int] = set()
    for method, template, path, body in steps:
        status, data = await call(http, api, method, path, body)
        check_response(doc, template, method, status, data)
        seen.add(status)
    status, data = await call(http, api, "POST", "/api/estop", raw="x" * 20000)
    check_response(doc, "/api/estop", "POST", status, data)
    status, data = await call(
        http, api, "POST", "/api/estop", raw="{}", headers={"Content-Type": "text/plain"}
    )
    check_response(doc, "/api/estop", "POST", status, data)
    assert seen == {200, 400, 404, 409}
    # WebSocket frames match their schemas too.
    schemas = doc["components"]["schemas"]
    async with http.ws_connect(api.url + "/api/ws") as ws:
        frames = [await ws.receive_json(timeout=2), await ws.receive_json(timeout=2)]
        await ws.send_json({"type": "estop", "id": 1, "engaged": False})
        await ws.send_json({"type": "preset", "id": 2, "name": "nope"})
        await ws.send_json({"type": "dance"})
        while len(frames) < 8:
            frames.append(await ws.receive_json(timeout=2))
    names = {
        "hello": "HelloFrame",
        "state": "StateFrame",
        "reply": "ReplyFrame",
        "error": "ErrorFrame",
    }
    kinds = set()
    for frame in frames:
        kinds.add(frame["type"])
        ref = {"$ref": f"#/components/schemas/{names[frame['type']]}"}
        errors = list(schema_validator(doc, ref).iter_errors(frame))
        assert not errors, (frame["type"], [e.message for e in errors])
    assert kinds == {"hello", "state", "reply", "error"}
    assert set(schemas) >= {"HelloFrame", "StateFrame", "ReplyFrame", "ErrorFrame", "TwistFrame"}
