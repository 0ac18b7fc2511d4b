"""Fixtures shared by every suite that runs the real daemon against the pty sim.

Registered from the root conftest (``pytest_plugins``), so ``sim`` and ``daemon``
mean the same thing in integration, API, ops and reliability tests.
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from lupin.config import load_profile
from lupin.daemon import Daemon, DaemonOptions
from lupintest.harness import Sim, start_sim

DEFAULT_SOAK_SECONDS = 120.0  # "minutes in CI", and the whole suite still inside its budget


def pytest_addoption(parser: pytest.Parser) -> None:
    # Here, not in tests/reliability/conftest.py: a sub-folder's conftest is read
    # after the command line is parsed, so the flag would be refused from the root.
    parser.addoption(
        "--soak-seconds",
        type=float,
        default=None,
        help=f"how long the reliability soak runs (default {DEFAULT_SOAK_SECONDS:.0f} s, "
        "or $LUPIN_SOAK_SECONDS)",
    )


@pytest.fixture()
async def sim(lupin_home: Path) -> AsyncIterator[Sim]:
    """The so101 profile's servos, simulated on a pty in the test's event loop."""
    s = await start_sim(load_profile("so101"))
    try:
        yield s
    finally:
        await s.server.close()


@pytest.fixture()
async def daemon(sim: Sim) -> AsyncIterator[Daemon]:
    """The real daemon on the sim, ready (first full state read), auto-home off."""
    d = Daemon(sim.profile, DaemonOptions(bus_port=sim.path, auto_home=False))
    await d.start()
    try:
        assert await d.wait_ready(3.0), "no complete joint state from the sim"
        yield d
    finally:
        await d.stop()
