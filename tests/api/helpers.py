"""Small HTTP helpers shared by the API tests."""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path
from typing import Any

import aiohttp

from lupin.api import ApiServer
from lupintest.harness import child_env, lupin_cmd


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


async def lupin(
    home: Path,
    *args: str,
    token: str | None = None,
    stdin: str | None = None,
    timeout: float = 20.0,
) -> tuple[int, str, str]:
    """Run ``python -m lupin ARGS`` to the end: (exit status, stdout, stderr).

    ``stdin`` is piped in (then closed); without it the child's stdin is empty.
    """
    env = child_env(home)
    env.pop("LUPIN_TOKEN", None)
    if token is not None:
        env["LUPIN_TOKEN"] = token
    proc = await asyncio.create_subprocess_exec(
        *lupin_cmd(*args),
        stdin=asyncio.subprocess.PIPE if stdin is not None else asyncio.subprocess.DEVNULL,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        env=env,
    )
    try:
        async with asyncio.timeout(timeout):
            out, err = await proc.communicate(None if stdin is None else stdin.encode())
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    assert proc.returncode is not None
    return proc.returncode, out.decode(), err.decode()


def free_port() -> int:
    """A port nothing listens on (bound and released), for the no-daemon cases."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
