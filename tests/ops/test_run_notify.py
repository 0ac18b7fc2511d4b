"""``lupin run`` as systemd runs it: a real process, a fake NOTIFY_SOCKET, a watchdog period.

Skipped until ``lupin/cli/run.py`` is wired to ``lupin.sdnotify`` (the lines are
in docs/operations.md); from then on it checks the real process end to end.
"""

from __future__ import annotations

import asyncio
import itertools
import signal
import time
from pathlib import Path

import pytest

import lupin.cli.run
from lupin import control_table as ct
from lupin.protocol import Instruction
from lupintest.harness import Sim, child_env, lupin_cmd, wait_for
from lupintest.notify import NotifySocket

pytestmark = pytest.mark.skipif(
    "lupin.sdnotify" not in Path(lupin.cli.run.__file__).read_text(),
    reason="lupin/cli/run.py does not use lupin.sdnotify yet (wiring pending)",
)

STATE_ADDR = ct.REGISTERS["present_position"].address
ALL_IDS = {1, 2, 3, 4, 5, 6, 7, 9}
INTERVAL_S = 1.0


async def test_ready_after_full_state_watchdog_while_alive_stopping_on_sigterm(
    sim: Sim, notify_socket: NotifySocket, lupin_home: Path
) -> None:
    ns = notify_socket
    env = child_env(lupin_home) | {
        "NOTIFY_SOCKET": ns.path,
        "WATCHDOG_USEC": str(int(INTERVAL_S * 1e6)),
    }
    sim.bus.kill(3)  # the port opens, but no full state until it answers
    proc = await asyncio.create_subprocess_exec(
        *lupin_cmd("run", "--port", "0", "--bus-port", sim.path),
        stdout=asyncio.subprocess.DEVNULL,
        stderr=asyncio.subprocess.DEVNULL,
        env=env,
    )
    try:
        await wait_for(lambda: len(ns.fields("WATCHDOG=1")) >= 2, timeout=20.0)
        assert ns.first("READY=1") is None

        t_revive = time.monotonic()
        sim.bus.revive(3)
        await wait_for(lambda: ns.first("READY=1") is not None, timeout=10.0)
        t_ready = ns.first("READY=1")
        assert t_ready is not None
        assert any(
            p.params[0] == STATE_ADDR and set(p.params[2:]) == ALL_IDS and t < t_ready
            for t, p in sim.packets(Instruction.SYNC_READ, since=t_revive)
        )

        t0 = time.monotonic()
        await asyncio.sleep(2.5)
        pings = [t for t, _ in ns.fields("WATCHDOG=1", since=t0)]
        assert len(pings) >= 3
        gaps = [b - a for a, b in itertools.pairwise([t0, *pings, time.monotonic()])]
        assert max(gaps) < INTERVAL_S

        # A frozen process sends nothing; systemd would kill it after WatchdogSec.
        proc.send_signal(signal.SIGSTOP)
        t_freeze = time.monotonic()
        await asyncio.sleep(1.5 * INTERVAL_S)
        assert ns.fields("WATCHDOG=1", since=t_freeze + 0.05) == []
        proc.send_signal(signal.SIGCONT)
        t_thaw = time.monotonic()
        await wait_for(lambda: ns.fields("WATCHDOG=1", since=t_thaw) != [], timeout=2.0)

        proc.send_signal(signal.SIGTERM)
        async with asyncio.timeout(5):
            assert await proc.wait() == 0
        assert ns.first("STOPPING=1") is not None
    finally:
        if proc.returncode is None:
            proc.send_signal(signal.SIGCONT)
            proc.kill()
            await proc.wait()
