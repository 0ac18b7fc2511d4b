"""The real daemon on the simulated bus, notifying a fake systemd socket.

READY=1 must wait for the first full state (not merely an open port), and
WATCHDOG=1 must come from the control tick: a stalled tick stops the pings even
though the process and its event loop are still alive, which is the case a
timer-driven ping would hide from systemd.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import os
import time
from collections.abc import AsyncIterator

import pytest

from lupin import control_table as ct
from lupin.daemon import Daemon, DaemonOptions
from lupin.protocol import Instruction
from lupin.sdnotify import SdNotifier, WatchdogPinger, announce_ready, watchdog_interval
from lupintest.harness import Sim, wait_for
from lupintest.notify import NotifySocket

INTERVAL_S = 0.4  # WatchdogSec for the test: pings every 0.2 s
STATE_ADDR = ct.REGISTERS["present_position"].address
ALL_IDS = {1, 2, 3, 4, 5, 6, 7, 9}


def wire_notify(daemon: Daemon, *, poll: float) -> tuple[SdNotifier, asyncio.Task[None]]:
    """The wiring proposed for ``lupin/cli/run.py``'s ``serve()``, line for line."""
    notifier = SdNotifier.from_env()
    assert notifier is not None and daemon.loop is not None
    interval = watchdog_interval()
    if interval is not None:
        daemon.loop.on_tick.append(WatchdogPinger(notifier, interval).on_tick)
    ready = asyncio.create_task(
        announce_ready(notifier, daemon.wait_ready, "ready: so101 on sim", poll=poll)
    )
    return notifier, ready


@pytest.fixture()
async def notified_daemon(
    sim: Sim, notify_socket: NotifySocket, monkeypatch: pytest.MonkeyPatch
) -> AsyncIterator[tuple[Daemon, SdNotifier]]:
    monkeypatch.setenv("NOTIFY_SOCKET", notify_socket.path)
    monkeypatch.setenv("WATCHDOG_USEC", str(int(INTERVAL_S * 1e6)))
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    # Servo 3 is silent at first: the port opens and ticks run, but no full state.
    sim.bus.kill(3)
    daemon = Daemon(sim.profile, DaemonOptions(bus_port=sim.path, auto_home=False))
    await daemon.start()
    notifier, ready_task = wire_notify(daemon, poll=0.2)
    try:
        yield daemon, notifier
    finally:
        ready_task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await ready_task
        notifier.stopping("stopping: zeroing wheels, limping the arm")
        await daemon.stop()
        notifier.close()


def gaps(times: list[float]) -> list[float]:
    return [b - a for a, b in itertools.pairwise(times)]


async def test_ready_only_after_first_full_state_then_watchdog_until_the_tick_stalls(
    sim: Sim, notify_socket: NotifySocket, notified_daemon: tuple[Daemon, SdNotifier]
) -> None:
    daemon, _ = notified_daemon
    ns = notify_socket

    # Port open, ticks running, one servo silent: pings, a status saying why, no READY.
    await asyncio.sleep(0.8)
    assert ns.first("READY=1") is None
    assert len(ns.fields("WATCHDOG=1")) >= 2
    assert any("no full joint state" in m for _, m in ns.messages)

    t_revive = time.monotonic()
    sim.bus.revive(3)
    await wait_for(lambda: ns.first("READY=1") is not None, timeout=3.0)
    t_ready = ns.first("READY=1")
    assert t_ready is not None and t_ready > t_revive
    # Before READY the sim had answered a full-state SYNC_READ that included servo 3.
    answered = [
        t
        for t, p in sim.packets(Instruction.SYNC_READ, since=t_revive)
        if p.params[0] == STATE_ADDR and set(p.params[2:]) == ALL_IDS and t < t_ready
    ]
    assert answered, "READY=1 arrived before any full state had been read"
    assert daemon.loop is not None and daemon.loop.first_state.is_set()
    assert [m for _, m in ns.fields("READY=1")] == ["READY=1\nSTATUS=ready: so101 on sim"]

    # Healthy: pings keep coming, never further apart than the watchdog interval.
    t0 = time.monotonic()
    await asyncio.sleep(1.2)
    pings = [t for t, _ in ns.fields("WATCHDOG=1", since=t0)]
    assert len(pings) >= 4
    assert max(gaps([t0, *pings, time.monotonic()])) < INTERVAL_S

    # Stall the tick itself (the event loop stays alive): the pings must stop.
    async def stuck() -> None:
        await asyncio.Event().wait()

    assert daemon.loop is not None
    daemon.loop.tick = stuck  # type: ignore[method-assign]
    t_stall = time.monotonic()
    await asyncio.sleep(3 * INTERVAL_S)
    late = [t for t, _ in ns.fields("WATCHDOG=1", since=t_stall + 0.05)]
    assert late == [], f"WATCHDOG=1 kept coming from a stalled tick: {late}"
    last = ns.fields("WATCHDOG=1")[-1][0]
    assert time.monotonic() - last > INTERVAL_S  # systemd would have fired by now


async def test_stopping_is_announced_on_shutdown(
    notify_socket: NotifySocket, notified_daemon: tuple[Daemon, SdNotifier]
) -> None:
    daemon, notifier = notified_daemon
    notifier.stopping("stopping: zeroing wheels, limping the arm")
    await wait_for(lambda: notify_socket.first("STOPPING=1") is not None, timeout=1.0)
    await daemon.stop()  # the fixture's second stop is harmless
