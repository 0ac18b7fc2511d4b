"""Harness: the real daemon against the simulated servo bus on a pty.

The simulator runs in the test's event loop, so a test can read every packet the
servos received, inject faults and move a limp joint by hand; the daemon talks
to it through the real serial path (pyserial-asyncio on the pty's slave end).
"""

from __future__ import annotations

import asyncio
import os
import sys
from dataclasses import dataclass
from pathlib import Path

from lupin.config_models import RobotProfile
from lupin.protocol import Instruction, Packet
from lupin_adapters.sim import PtySimServer, SimulatedBus, build_sim_bus
from lupin_adapters.sim.link import sim_specs


@dataclass
class Sim:
    bus: SimulatedBus
    server: PtySimServer
    path: str
    profile: RobotProfile

    def packets(self, code: int, since: float = float("-inf")) -> list[tuple[float, Packet]]:
        return self.bus.instructions(code, since=since)

    def sync_reads(self, since: float = float("-inf")) -> list[float]:
        return [t for t, _ in self.packets(Instruction.SYNC_READ, since)]

    def all_writes(self, since: float = float("-inf")) -> list[tuple[float, Packet]]:
        out = []
        for code in (Instruction.WRITE, Instruction.SYNC_WRITE, Instruction.REG_WRITE):
            out += self.packets(code, since)
        return sorted(out, key=lambda tp: tp[0])


async def start_sim(profile: RobotProfile) -> Sim:
    bus = build_sim_bus(sim_specs(profile))
    server = PtySimServer(bus, baud=profile.bus.baud)
    path = await server.start()
    return Sim(bus, server, path, profile)


async def wait_for(predicate: object, timeout: float = 3.0, step: float = 0.005) -> None:
    """Poll ``predicate()`` until true; fail the test on timeout."""
    assert callable(predicate)
    deadline = asyncio.get_running_loop().time() + timeout
    while not predicate():
        if asyncio.get_running_loop().time() > deadline:
            raise AssertionError(f"condition not met within {timeout} s")
        await asyncio.sleep(step)


def lupin_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "lupin", *args]


def child_env(home: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["LUPIN_HOME"] = str(home)
    env.pop("JOURNAL_STREAM", None)
    # Auto-home energises the arm 2 s after boot; tests that want it turn it on.
    env.setdefault("LUPIN_AUTO_HOME", "false")
    return env
