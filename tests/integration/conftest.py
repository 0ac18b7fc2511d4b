"""Integration fixtures: the real daemon against the simulated servo bus on a pty."""

from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from lupin.config import load_profile
from lupin.daemon import Daemon, DaemonOptions
from lupintest.harness import Sim, start_sim


@pytest.fixture()
async def sim(lupin_home: Path) -> AsyncIterator[Sim]:
    s = await start_sim(load_profile("so101"))
    try:
        yield s
    finally:
        await s.server.close()


@pytest.fixture()
async def daemon(sim: Sim) -> AsyncIterator[Daemon]:
    d = Daemon(sim.profile, DaemonOptions(bus_port=sim.path, auto_home=False))
    await d.start()
    try:
        assert await d.wait_ready(3.0), "no complete joint state from the sim"
        yield d
    finally:
        await d.stop()
