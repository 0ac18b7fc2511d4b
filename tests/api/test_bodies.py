"""Request bodies: strict JSON, strict types, named fields, size limits; refusals change nothing."""

from __future__ import annotations

import aiohttp
import pytest

from lupin.api import ApiServer
from lupin.api.bodies import loads
from lupin.api.errors import ApiError
from lupin.daemon import Daemon

from .helpers import call, error_code, torque_on

NOT_FINITE = ["NaN", "Infinity", "-Infinity", "1e400", "-1e400"]


@pytest.mark.parametrize("literal", NOT_FINITE)
def test_loads_refuses_non_finite_numbers(literal: str) -> None:
    with pytest.raises(ApiError) as err:
        loads(f'{{"angle_deg": {literal}}}')
    assert err.value.status == 400 and err.value.code == "invalid_json"


def test_loads_keeps_ordinary_numbers() -> None:
    assert loads('{"a": 1, "b": -2.5e3, "c": 1e300}') == {"a": 1, "b": -2500.0, "c": 1e300}


@pytest.mark.parametrize("literal", NOT_FINITE)
async def test_non_finite_numbers_refused_on_every_numeric_field(
    http: aiohttp.ClientSession, api: ApiServer, daemon: Daemon, literal: str
) -> None:
    await torque_on(http, api)
    before = dict(daemon.arm.commanded or {})
    cases = [
        ("/api/arm/joints/elbow_flex", f'{{"angle_deg": {literal}}}'),
        ("/api/arm/joints/elbow_flex", f'{{"angle_deg": 1, "speed_deg_s": {literal}}}'),
        ("/api/arm/gripper", f'{{"angle_deg": {literal}}}'),
        ("/api/base/twist", f'{{"source": "manual", "angular_z": {literal}}}'),
        ("/api/arm/poses/p/go", f'{{"speed_rad_s": {literal}}}'),
        ("/api/arm/poses/p", f'{{"joints_rad": {{"elbow_flex": {literal}}}}}'),
    ]
    for path, raw in cases:
        method = "PUT" if path == "/api/arm/poses/p" else "POST"
        status, data = await call(http, api, method, path, raw=raw)
        assert status == 400 and error_code(data) == "invalid_json", (path, raw, data)
    assert daemon.arm.commanded == before
    assert daemon.mux.status(daemon.clock()).active is None
    assert (await call(http, api, "GET", "/api/arm/poses"))[1] == {"poses": []}


async def test_unknown_fields_are_refused_by_name(
    http: aiohttp.ClientSession, api: ApiServer
) -> None:
    cases = [
        ("/api/estop", {"engaged": True, "force": True}, "force"),
        ("/api/arm/torque", {"enabled": True, "joint": "elbow_flex"}, "joint"),
        ("/api/base/twist", {"source": "manual", "linear_z": 1.0}, "linear_z"),
        ("/api/arm/joints/elbow_flex", {"angle_deg": 1.0, "angle_rad": 0.1}, "angle_rad"),
    ]
    for path, body, field in cases:
        status, data = await call(http, api, "POST", path, body)
        assert status == 400 and error_code(data) == "invalid_body"
        assert field in data["error"]["message"], data


async def test_wrong_types_are_refused_not_coerced(
    http: aiohttp.ClientSession, api: ApiServer, daemon: Daemon
) -> None:
    cases = [
        ("/api/estop", {"engaged": "true"}),
        ("/api/estop", {"engaged": 0}),
        ("/api/base/twist", {"source": "manual", "linear_x": "0.1"}),
        ("/api/base/twist", {"source": ["manual"]}),
        ("/api/arm/joints/elbow_flex", {"angle_deg": True}),
    ]
    for path, body in cases:
        status, data = await call(http, api, "POST", path, body)
        assert status == 400 and error_code(data) == "invalid_body", (body, data)
    assert not daemon.estop


async def test_invalid_json_and_non_objects(http: aiohttp.ClientSession, api: ApiServer) -> None:
    for raw in ("{", "engaged=true", "\xff\xfe", "[true]", "true", '"x"'):
        status, data = await call(http, api, "POST", "/api/estop", raw=raw.encode("latin-1"))
        assert status == 400 and error_code(data) in ("invalid_json", "invalid_body"), raw


async def test_json_content_type_required_for_a_body(
    http: aiohttp.ClientSession, api: ApiServer, daemon: Daemon
) -> None:
    # A text/plain POST is a CORS "simple request": refusing it keeps foreign pages out.
    headers = {"Content-Type": "text/plain"}
    status, data = await call(
        http, api, "POST", "/api/estop", raw='{"engaged": true}', headers=headers
    )
    assert status == 415 and error_code(data) == "unsupported_media_type"
    assert not daemon.estop


async def test_oversized_body_is_413_with_error_body(
    http: aiohttp.ClientSession, api: ApiServer
) -> None:
    limit = api.config.max_body_bytes
    big = '{"source": "manual", "pad": "' + "x" * limit + '"}'
    status, data = await call(http, api, "POST", "/api/base/twist", raw=big)
    assert status == 413 and error_code(data) == "body_too_large"
    assert str(limit) in data["error"]["message"]
    # The server is still fine afterwards.
    assert (await call(http, api, "GET", "/api/health"))[0] == 200


async def test_body_on_a_bodyless_endpoint(http: aiohttp.ClientSession, api: ApiServer) -> None:
    assert (await call(http, api, "POST", "/api/heal", {}))[0] == 200
    status, data = await call(http, api, "POST", "/api/arm/presets/home", {"fast": True})
    assert status == 400 and error_code(data) == "invalid_body"


async def test_unexpected_exception_is_500_with_body_and_logged(
    http: aiohttp.ClientSession,
    api: ApiServer,
    daemon: Daemon,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    def boom() -> None:
        raise RuntimeError("a bug")

    monkeypatch.setattr(daemon.services, "health", boom)
    status, data = await call(http, api, "GET", "/api/health")
    assert status == 500 and error_code(data) == "internal"
    assert "a bug" not in data["error"]["message"]  # details go to the log, not the client
    logged = [r for r in caplog.records if r.name == "lupin.api.errors"]
    assert logged and "GET /api/health" in logged[0].getMessage() and logged[0].exc_info
    caplog.clear()  # expected here; the autouse check forbids it everywhere else
