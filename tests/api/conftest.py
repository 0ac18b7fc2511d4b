"""API fixtures: the real daemon on the pty sim, with the API on a real port.

``api`` has no token; ``api_token`` requires :data:`TOKEN`. Every test here
also asserts that nothing was logged at ERROR by the API: bad input must be
answered 4xx, never become an unhandled exception.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator, Iterator

import aiohttp
import pytest

from lupin.api import ApiServer
from lupin.api.ws import WsSettings
from lupin.daemon import Daemon

TOKEN = "tok-7f3a9c1e5b2d4f60a8e1c3b5d7f9a0b2"


async def start_api(
    daemon: Daemon, *, token: str | None = None, ws: WsSettings | None = None, **api: object
) -> ApiServer:
    config = daemon.profile.api.model_copy(update={"port": 0, "token": token, **api})
    server = ApiServer(daemon.services, config, env={}, ws_settings=ws)
    await server.start()
    return server


@pytest.fixture()
async def api(daemon: Daemon) -> AsyncIterator[ApiServer]:
    server = await start_api(daemon)
    try:
        yield server
    finally:
        await server.stop()


@pytest.fixture()
async def api_token(daemon: Daemon) -> AsyncIterator[ApiServer]:
    server = await start_api(daemon, token=TOKEN)
    try:
        yield server
    finally:
        await server.stop()


@pytest.fixture()
async def http() -> AsyncIterator[aiohttp.ClientSession]:
    async with aiohttp.ClientSession() as session:
        yield session


@pytest.fixture(autouse=True)
def no_api_errors(caplog: pytest.LogCaptureFixture) -> Iterator[None]:
    caplog.set_level(logging.INFO)
    yield
    bad = [
        r
        for r in caplog.records
        if r.levelno >= logging.ERROR and r.name.startswith(("lupin.api", "aiohttp"))
    ]
    assert not bad, f"the API logged errors: {[r.getMessage() for r in bad]}"
