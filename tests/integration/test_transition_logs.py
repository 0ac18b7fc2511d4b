"""Every state transition an operator needs to reconstruct from the journal is logged, once.

E-stop, servo lost/back and base blocked were already logged; these cover the
ones that were silent: who drives the base (mux source), arm torque off, the
wheels being energised, and the pad coming and going.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator

import pytest

from lupin import api_models as m
from lupin.config import load_profile
from lupin.daemon import Daemon, DaemonOptions
from lupin.mux import Twist
from lupin.pad import PadFrame
from lupin.pad_mapping import load_mapping
from lupin.pad_task import run_pad
from lupin.teleop import BaseTeleop
from lupintest.harness import Sim, wait_for


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def mux_lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.getMessage().startswith("mux:")]


def test_each_change_of_the_driving_source_is_logged_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger="lupin.daemon")
    clock = FakeClock()
    d = Daemon(load_profile("so101"), DaemonOptions(), clock=clock)
    d._mux_output(0.0)  # nothing, as at start: no line
    d.submit_twist("manual", Twist(linear_x=0.1))
    for _ in range(3):  # the tick asks every 10 ms; one change, one line
        d._mux_output(clock.now)
    clock.now = 0.1
    d.submit_twist("auto", Twist(linear_x=0.1))  # lower priority: manual keeps the base
    d._mux_output(clock.now)
    clock.now = 0.7  # manual (0.5 s) expired, auto (0.5 s) expired too
    d._mux_output(clock.now)
    assert mux_lines(caplog) == [
        "mux: manual drives the base (was nothing)",
        "mux: nothing drives the base (was manual)",
    ]


async def test_estop_lock_is_named_when_it_takes_the_base(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger="lupin.daemon")
    clock = FakeClock()
    d = Daemon(load_profile("so101"), DaemonOptions(), clock=clock)
    d.submit_twist("manual", Twist(linear_x=0.1))
    d._mux_output(0.0)
    await d.set_estop(True)
    d._mux_output(0.01)
    assert mux_lines(caplog)[-1] == "mux: nothing drives the base (was manual), locked by estop"


async def test_arm_torque_off_and_wheel_torque_on_are_logged(
    sim: Sim, daemon: Daemon, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO)
    assert (await daemon.services.set_torque(m.TorqueRequest(enabled=True))).torque == "on"
    assert "arm torque on; command gate open" in caplog.text
    await daemon.services.set_torque(m.TorqueRequest(enabled=False))
    assert "arm torque off; command gate closed" in caplog.text
    daemon.submit_twist("manual", Twist(linear_x=0.1))
    await wait_for(lambda: "wheel torque on" in caplog.text)
    await wait_for(lambda: sim.bus.servo(7).torque and sim.bus.servo(9).torque)
    assert "wheel torque on (speed zeroed first): ['wheel left', 'wheel right']" in caplog.text


class Replayed:
    """A reader: a frame, the pad vanishes, it is back, then its frames end."""

    name, transport = "test-pad", "test"

    async def frames(self) -> AsyncIterator[PadFrame | None]:
        idle = PadFrame(0.0, (0.0,) * 4 + (1.0, 1.0, 0.0, 0.0), (0,) * 15)
        for item in (idle, idle, None, idle):
            await asyncio.sleep(0.01)
            yield item

    async def close(self) -> None:
        return None


async def test_the_pad_coming_and_going_is_logged_once_each(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger="lupin.pad_task")
    await run_pad(
        Replayed,
        BaseTeleop(load_mapping("xbox-bluetooth")),
        None,
        submit_twist=lambda source, twist: None,
        arm=None,
        clock=asyncio.get_running_loop().time,
    )
    assert [r.getMessage() for r in caplog.records] == [
        "pad test-pad: connected",
        "pad test-pad: gone (counts as released)",
        "pad test-pad: connected",
        "pad test-pad: no more frames",
        "pad test-pad: gone (counts as released)",  # frames that end count as a vanish
    ]
