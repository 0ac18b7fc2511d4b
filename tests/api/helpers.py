"""Small HTTP helpers shared by the API tests."""

from __future__ import annotations

from typing import Any

import aiohttp

from lupin.api import ApiServer


async def call(
    http: aiohttp.ClientSession,
    api: ApiServer,
    method: str,
    path: str,
    body: Any = None,
    *,
    raw: str | bytes | None = None,
    headers: dict[str, str] | None = None,
) -> tuple[int, Any]:
    """(status, parsed JSON body or None). ``raw`` is sent as-is with a JSON content type."""
    hdrs = dict(headers or {})
    kwargs: dict[str, Any] = {}
    if raw is not None:
        hdrs.setdefault("Content-Type", "application/json")
        kwargs["data"] = raw
    elif body is not None:
        kwargs["json"] = body
    async with http.request(method, api.url + path, headers=hdrs, **kwargs) as resp:
        try:
            data = await resp.json(content_type=None)
        except ValueError:
            data = None
        return resp.status, data


def error_code(data: Any) -> str:
    assert isinstance(data, dict) and set(data) == {"error"}, data
    assert set(data["error"]) == {"code", "message"}, data
    assert data["error"]["message"], data
    return str(data["error"]["code"])


async def torque_on(http: aiohttp.ClientSession, api: ApiServer) -> None:
    status, data = await call(http, api, "POST", "/api/arm/torque", {"enabled": True})
    assert (status, data) == (200, {"torque": "on"})
