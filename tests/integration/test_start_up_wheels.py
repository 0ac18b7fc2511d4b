"""Start-up after a death nobody cleaned up: wheels left spinning are stopped, the arm is held.

A SIGKILL (or OOM kill) with no stop helper leaves each wheel in velocity mode
turning at its last goal speed. The new daemon's base starts from goal 0 and
would never write one, so it must stop them itself at start-up.
"""

from __future__ import annotations

import asyncio
import logging
import time

import pytest

from lupin import control_table as ct
from lupin.arm import Torque
from lupin.daemon import Daemon, DaemonOptions
from lupintest.harness import Sim

GOAL_POS = ct.REGISTERS["goal_position"].address
ARM = [1, 2, 3, 4, 5, 6]
WHEELS = [7, 9]


async def started(sim: Sim) -> Daemon:
    d = Daemon(sim.profile, DaemonOptions(bus_port=sim.path, auto_home=False))
    await d.start()
    assert await d.wait_ready(3.0)
    return d


async def test_wheels_found_spinning_are_zeroed_then_limped_and_the_arm_left_holding(
    sim: Sim, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING)
    for sid in ARM + WHEELS:
        sim.bus.servo(sid).set("torque_enable", 1)
    sim.bus.servo(7).set("goal_speed", 600)
    sim.bus.servo(9).set("goal_speed", -600)
    held = {sid: sim.bus.servo(sid).get("goal_position") for sid in ARM}
    t0 = time.monotonic()
    d = await started(sim)
    try:
        await asyncio.sleep(0.2)
        writes = sim.bus.writes(since=t0)
        assert [w for w in writes if w.id in ARM] == []
        assert [(w.id, w.address, w.data) for w in writes] == [
            (7, ct.REGISTERS["goal_speed"].address, b"\x00\x00"),
            (9, ct.REGISTERS["goal_speed"].address, b"\x00\x00"),
            (7, ct.REGISTERS["torque_enable"].address, b"\x00"),
            (9, ct.REGISTERS["torque_enable"].address, b"\x00"),
        ]
        assert [sim.bus.servo(w).get("goal_speed") for w in WHEELS] == [0, 0]
        assert not any(sim.bus.servo(w).torque for w in WHEELS)
        # The arm: left holding exactly where it was, commands gated until torque is set.
        assert {sid: sim.bus.servo(sid).get("goal_position") for sid in ARM} == held
        assert d.arm.torque_summary is Torque.UNKNOWN
        assert "found energised at start-up" in caplog.text
    finally:
        await d.stop()


async def test_a_wheel_in_the_wrong_mode_found_energised_is_limped_not_given_a_speed(
    sim: Sim,
) -> None:
    sim.bus.servo(7).set("operating_mode", 0)  # position mode: goal_speed is not a speed here
    sim.bus.servo(7).set("torque_enable", 1)
    t0 = time.monotonic()
    d = await started(sim)
    try:
        writes = sim.bus.writes(since=t0)
        assert [(w.id, w.address, w.data) for w in writes] == [
            (7, ct.REGISTERS["torque_enable"].address, b"\x00")
        ]
        assert d.loop is not None and 7 in d.loop.wheels_excluded
    finally:
        await d.stop()


async def test_limp_wheels_at_start_up_get_nothing(sim: Sim) -> None:
    t0 = time.monotonic()
    d = await started(sim)
    try:
        await asyncio.sleep(0.1)
        assert sim.bus.writes(since=t0) == []
    finally:
        await d.stop()
