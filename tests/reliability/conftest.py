"""Reliability fixtures: the real daemon on the pty sim, the API on a real port, the soak budget.

``--soak-seconds N`` (or ``LUPIN_SOAK_SECONDS=N``) sets how long the soak runs;
the default keeps the whole suite inside its CI budget. The flag is registered
here, so pass it with this folder (or a file in it) on the command line:
``pytest tests/reliability --soak-seconds 1800``; the variable works from anywhere.
"""

from __future__ import annotations

import os
from collections.abc import AsyncIterator
from pathlib import Path

import aiohttp
import pytest

from lupin.api import ApiServer
from lupin.config import load_profile
from lupintest.harness import Sim, start_sim

DEFAULT_SOAK_SECONDS = 60.0


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--soak-seconds",
        type=float,
        default=None,
        help=f"how long the reliability soak runs (default {DEFAULT_SOAK_SECONDS:.0f} s, "
        "or $LUPIN_SOAK_SECONDS)",
    )


@pytest.fixture()
def soak_seconds(request: pytest.FixtureRequest) -> float:
    flag = request.config.getoption("soak_seconds", default=None)
    if flag is not None:
        return float(flag)
    env = os.environ.get("LUPIN_SOAK_SECONDS")
    return float(env) if env else DEFAULT_SOAK_SECONDS


@pytest.fixture()
async def sim(lupin_home: Path) -> AsyncIterator[Sim]:
    s = await start_sim(load_profile("so101"))
    try:
        yield s
    finally:
        await s.server.close()


@pytest.fixture()
async def http() -> AsyncIterator[aiohttp.ClientSession]:
    async with aiohttp.ClientSession() as session:
        yield session


__all__ = ["ApiServer"]
