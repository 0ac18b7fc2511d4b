"""The daemon: wires profile, bus, control loop and mux together, and owns shutdown.

Safety properties that live here:
* boot limp: opening the bus writes nothing; torque is only ever enabled on request;
* a bad config or a bus that cannot be opened fails before anything moves;
* stop (SIGTERM/SIGINT) zeroes the wheels and limps the arm before releasing the port.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from lupin import control_table as ct
from lupin import registry
from lupin.arm import ArmCommander, Torque
from lupin.base import BaseDrive
from lupin.bus import PRIORITY_CONTROL, ServoBus
from lupin.config_models import RobotProfile
from lupin.control_loop import ControlLoop
from lupin.joints import arm_geometry
from lupin.mux import LockSpec, SourceSpec, TakeoverMux, Twist, VelocityMux

log = logging.getLogger(__name__)

ESTOP_LOCK = "estop"
ESTOP_PRIORITY = 256  # above every configurable priority (0-255)
MODE_POSITION, MODE_VELOCITY = ct.OperatingMode.POSITION, ct.OperatingMode.VELOCITY


class BusOpenError(Exception):
    """The bus could not be opened; nothing was sent."""


@dataclass
class DaemonOptions:
    sim: bool = False
    bus_port: str | None = None
    sim_wire_pacing: bool = False


def build_mux(profile: RobotProfile, *, sim: bool) -> VelocityMux | TakeoverMux:
    cfg = profile.mux
    sources = [
        SourceSpec(name, t.priority, t.timeout)
        for name, t in cfg.topics.items()
        if sim or not t.sim_only
    ]
    if cfg.mode == "takeover":
        # The runbook's two-source cmd_vel_mux: the pad feeds `manual` in this mode.
        pair = [s for s in sources if s.name in (TakeoverMux.MANUAL, TakeoverMux.AUTO)]
        return TakeoverMux(pair, manual_takeover_seconds=cfg.manual_takeover_seconds)
    locks = [LockSpec(name, t.priority, t.timeout) for name, t in cfg.locks.items()]
    locks.append(LockSpec(ESTOP_LOCK, ESTOP_PRIORITY, 0.0))
    return VelocityMux(sources, locks)


class Daemon:
    def __init__(
        self,
        profile: RobotProfile,
        options: DaemonOptions | None = None,
        *,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.profile = profile
        self.options = options or DaemonOptions()
        self.clock = clock
        self.geometry = arm_geometry(profile.arm)
        self.arm = ArmCommander(
            self.geometry,
            resync_threshold=profile.arm.resync_threshold_rad,
            goal_tolerance=profile.arm.goal_tolerance_rad,
        )
        self.base = BaseDrive(profile.base) if profile.base else None
        self.mux = build_mux(profile, sim=self.options.sim)
        self.estop = False
        self.bus: ServoBus | None = None
        self.loop: ControlLoop | None = None
        self._tasks: list[asyncio.Task[Any]] = []
        self._link_closer: Any = None

    # -- lifecycle ------------------------------------------------------------

    async def start(self) -> None:
        name = "sim" if self.options.sim else "serial"
        opener = registry.load("lupin.bus", name)
        port = self.options.bus_port or self.profile.bus.port
        try:
            link = await opener(
                port,
                self.profile.bus.baud,
                profile=self.profile,
                wire_pacing=self.options.sim_wire_pacing,
            )
        except Exception as exc:
            raise BusOpenError(f"cannot open the servo bus ({name} {port}): {exc}") from exc
        self.bus = ServoBus(
            link, reply_margin_s=self.profile.bus.reply_margin_s, retries=self.profile.bus.retries
        )
        self.bus.start()
        self.loop = ControlLoop(
            self.bus,
            self.arm,
            self.geometry,
            self.base,
            self._mux_output,
            tick_hz=self.profile.control.tick_hz,
            health_every=self.profile.control.health_every_ticks,
            clock=self.clock,
        )
        await self.verify_servos()
        self._tasks.append(asyncio.create_task(self.loop.run(), name="control-loop"))

    async def stop(self) -> None:
        """Stop ticking, zero the wheels, limp the arm, release the port."""
        if self.loop is not None:
            self.loop.stop()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await asyncio.wait_for(task, 0.5)
        self._tasks.clear()
        if self.loop is not None and self.bus is not None:
            try:
                await asyncio.wait_for(self.loop.safe_stop(), 0.3)
            except Exception:
                log.exception("could not send the safe-stop sequence")
        if self.bus is not None:
            await self.bus.close()
            self.bus = None
        log.info("stopped: wheels zeroed, arm limp, port released")

    async def wait_ready(self, timeout: float = 5.0) -> bool:
        """True once the first full joint state has been read."""
        if self.loop is None:
            return False
        try:
            await asyncio.wait_for(self.loop.first_state.wait(), timeout)
        except TimeoutError:
            return False
        return True

    # -- start-up checks --------------------------------------------------------

    async def verify_servos(self) -> None:
        """Read back operating mode and torque; exclude a servo in the wrong mode.

        Mode changes are verified, never blind-written to EEPROM: a position goal
        sent to a servo in wheel mode is obeyed as a speed (bring-up seed).
        """
        assert self.bus is not None and self.loop is not None
        mode_addr = ct.REGISTERS["operating_mode"].address
        span = ct.REGISTERS["torque_enable"].address - mode_addr + 1
        result = await self.bus.sync_read(self.loop.ids, mode_addr, span, retries=2)
        for name, geo in self.geometry.items():
            data = result.data.get(geo.id)
            if data is None:
                log.warning("%s (id %d) did not answer at start-up", name, geo.id)
                continue
            if data[0] != MODE_POSITION:
                reason = f"operating mode reads {data[0]}, expected {MODE_POSITION} (position)"
                self.arm.excluded[name] = reason
                log.error("%s (id %d) excluded from control: %s", name, geo.id, reason)
            self.arm.set_torque_state(name, Torque.ON if data[-1] else Torque.OFF)
        if self.base is not None:
            for wheel in self.profile.base.wheels if self.profile.base else []:
                data = result.data.get(wheel.id)
                if data is None:
                    log.warning("wheel %s (id %d) did not answer at start-up", wheel.name, wheel.id)
                elif data[0] != MODE_VELOCITY:
                    reason = f"operating mode reads {data[0]}, expected {MODE_VELOCITY} (velocity)"
                    self.loop.wheels_excluded[wheel.id] = reason
                    log.error("wheel %s excluded from control: %s", wheel.name, reason)
        if any(self.arm.torque[n] is Torque.ON for n in self.arm.names):
            # Torque found on at boot (a previous run died without limping): say so;
            # the command gate stays closed until an operator enables or disables.
            log.warning("arm torque found ON at start-up; commands refused until torque is set")
            for n in self.arm.names:
                self.arm.set_torque_state(n, Torque.UNKNOWN)

    # -- commands used by the API and teleop -----------------------------------

    def _mux_output(self, now: float) -> tuple[Twist | None, float]:
        out = self.mux.output(now)
        if out.twist is None or out.source is None:
            return None, -math.inf
        return out.twist, self.mux.last_seen(out.source)

    def submit_twist(self, source: str, twist: Twist) -> None:
        self.mux.submit(source, twist, self.clock())

    async def set_estop(self, engaged: bool) -> None:
        self.estop = engaged
        if isinstance(self.mux, VelocityMux):
            self.mux.set_lock(ESTOP_LOCK, engaged, self.clock())
        self.arm.estop = engaged
        if self.loop is not None:
            self.loop.estop = engaged
        if engaged:
            self.arm.hold(self.clock())
            log.warning("E-stop ENGAGED: wheels zeroed, arm holding, motion refused")
        else:
            log.warning("E-stop released")

    async def enable_torque(self) -> None:
        assert self.loop is not None
        self.loop.request_enable()

    async def disable_torque(self) -> None:
        assert self.loop is not None
        await self.loop.disable_torque()


__all__ = ["PRIORITY_CONTROL", "BusOpenError", "Daemon", "DaemonOptions", "build_mux"]
