"""Fixtures for the bench tools' tests: simulated buses and tools on pseudo-terminals."""

from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from benchkit import MakeSim, Sim, StartTool, Tool, start_sim

from lupintest.harness import child_env


@pytest.fixture()
async def make_sim(lupin_home: Path) -> AsyncIterator[MakeSim]:
    """``await make_sim(positions={1: 3900})``: the so101 servos on a pty, closed at the end."""
    sims: list[Sim] = []

    async def make(**kwargs: Any) -> Sim:
        sim = await start_sim(**kwargs)
        sims.append(sim)
        return sim

    try:
        yield make
    finally:
        for sim in sims:
            await sim.server.close()


@pytest.fixture()
async def tools(make_sim: MakeSim, lupin_home: Path) -> AsyncIterator[StartTool]:
    """``tools("check", "--bus-port", p)`` starts a tool; each is killed (if need be) and reaped.

    It depends on ``make_sim`` so the tools go before the simulator they talk to.
    """
    started: list[Tool] = []

    def start(*args: str) -> Tool:
        tool = Tool(args, child_env(lupin_home))
        started.append(tool)
        return tool

    try:
        yield start
    finally:
        for tool in started:
            await tool.close()
