"""Reliability fixtures: the real daemon on the pty sim, the API on a real port, the soak budget.

``--soak-seconds N`` (or ``LUPIN_SOAK_SECONDS=N``) sets how long the soak runs;
the default keeps the whole suite inside its CI budget. The flag is registered by
the shared fixtures plugin, so it works from anywhere:
``pytest tests/reliability --soak-seconds 1800``.
The ``sim`` fixture is the shared one (``lupintest.fixtures``).
"""

from __future__ import annotations

import os
from collections.abc import AsyncIterator

import aiohttp
import pytest

from lupintest.fixtures import DEFAULT_SOAK_SECONDS


@pytest.fixture()
def soak_seconds(request: pytest.FixtureRequest) -> float:
    flag = request.config.getoption("soak_seconds", default=None)
    if flag is not None:
        return float(flag)
    env = os.environ.get("LUPIN_SOAK_SECONDS")
    return float(env) if env else DEFAULT_SOAK_SECONDS


@pytest.fixture()
async def http() -> AsyncIterator[aiohttp.ClientSession]:
    async with aiohttp.ClientSession() as session:
        yield session
