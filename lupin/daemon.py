"""The daemon: wires profile, bus, control loop and mux together, and owns shutdown.

Safety properties that live here:
* boot limp: opening the bus writes nothing; torque is only ever enabled on request;
* a bad config or a bus that cannot be opened fails before anything moves;
* stop (SIGTERM/SIGINT) zeroes the wheels and limps the arm before releasing the port.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from lupin import control_table as ct
from lupin import registry
from lupin.arm import ArmCommander, Torque
from lupin.arm_status import StallEvent, StallMonitor
from lupin.base import BaseDrive
from lupin.bus import ServoBus
from lupin.config import ConfigError
from lupin.config_models import RobotProfile
from lupin.control_loop import ControlLoop
from lupin.heal import (
    AutoHomeState,
    HealReport,
    ResumeWatcher,
    auto_home,
    auto_home_enabled,
    heal,
)
from lupin.joints import arm_geometry
from lupin.mux import LockSpec, SourceSpec, Twist, VelocityMux
from lupin.pad import open_pad
from lupin.pad_mapping import load_mapping, resolve_layout
from lupin.pad_task import PadStatus, run_pad
from lupin.services import Services
from lupin.takeover_mux import TakeoverMux
from lupin.teleop import ArmTeleop, BaseTeleop

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
    # None: follow $LUPIN_AUTO_HOME (default on). Tests that need a limp arm say False.
    auto_home: bool | None = None
    pad: str = "none"  # --pad auto|none|evdev:DEV|hid:VID:PID|replay:FILE
    pad_layout: str | None = None  # --pad-layout; None = detect the transport


class PadError(Exception):
    """The pad set-up is wrong (bad spec, bad mapping or replay file); nothing moved."""


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
        self.restarts: list[str] = []  # crashed tasks restarted since the last heal
        self.stalls = StallMonitor(self.arm.traj, on_stall=self._on_stall)
        self.auto_home_state: AutoHomeState | None = None
        self.last_heal: HealReport | None = None
        self.pad_info: dict[str, object] | None = None
        self.pad_status: PadStatus | None = None
        self._mux_active: str | None = None  # the source driving the base, as last logged
        self.services = Services(self)

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
        self.loop.on_state.append(self._after_tick)
        self._spawn("control-loop", self.loop.run)
        self._spawn("resume-watch", self._watch_resume)
        want_home = self.options.auto_home
        if want_home is None:
            want_home = auto_home_enabled()
        self.auto_home_state = "pending" if want_home else "disabled"
        self._tasks.append(asyncio.create_task(self._boot_heal(want_home), name="boot-heal"))

    def _spawn(self, name: str, factory: Callable[[], Any]) -> None:
        """Run a long-lived task, restarting it with backoff if it crashes."""

        async def supervised() -> None:
            backoff = 0.1
            while True:
                try:
                    await factory()
                    return
                except asyncio.CancelledError:
                    raise
                except Exception:
                    log.exception("%s crashed; restarting in %.1f s", name, backoff)
                    self.restarts.append(name)
                    await asyncio.sleep(backoff)
                    backoff = min(backoff * 2, 5.0)

        self._tasks.append(asyncio.create_task(supervised(), name=name))

    async def stop(self) -> bool:
        """Stop ticking, zero the wheels, limp the arm, release the port.

        Returns False when the safe-stop sequence could not be sent.
        """
        safe = self.loop is None
        if self.loop is not None:
            self.loop.stop()
        for task in self._tasks:
            if task.get_name() != "control-loop":
                task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await asyncio.wait_for(task, 0.5)
        self._tasks.clear()
        if self.loop is not None and self.bus is not None:
            try:
                await asyncio.wait_for(self.loop.safe_stop(), 0.3)
                safe = True
            except Exception:
                log.exception("could not send the safe-stop sequence")
        if self.bus is not None:
            await self.bus.close()
            self.bus = None
        if safe:
            log.info("stopped: wheels zeroed, arm limp, port released")
        else:
            log.error("stopped WITHOUT the safe-stop sequence: the stop helper must limp the arm")
        return safe

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
            spinning: dict[int, bytes] = {}
            energised: dict[int, bytes] = {}
            for wheel in self.profile.base.wheels if self.profile.base else []:
                data = result.data.get(wheel.id)
                if data is None:
                    log.warning("wheel %s (id %d) did not answer at start-up", wheel.name, wheel.id)
                    continue
                if data[0] != MODE_VELOCITY:
                    reason = f"operating mode reads {data[0]}, expected {MODE_VELOCITY} (velocity)"
                    self.loop.wheels_excluded[wheel.id] = reason
                    log.error("wheel %s excluded from control: %s", wheel.name, reason)
                if data[-1]:
                    log.warning(
                        "stopping wheel %s (id %d): found energised at start-up (a previous "
                        "run died without its safe stop); speed 0, torque off",
                        wheel.name,
                        wheel.id,
                    )
                    energised[wheel.id] = b"\x00"
                    if data[0] == MODE_VELOCITY:
                        spinning[wheel.id] = ct.encode_value(ct.REGISTERS["goal_speed"], 0)
            # A wheel in velocity mode keeps turning at its last goal speed as long as its
            # torque is on: after a SIGKILL that no stop helper cleaned up, the robot would
            # drive on while this daemon reports the base idle (its goals start at 0, so it
            # would never write one). Stop it as safe_stop does: zero speed, then limp.
            # Wheels only: an energised arm is left holding (limping it would drop it).
            if energised:
                goal_speed = ct.REGISTERS["goal_speed"].address
                await self.bus.sync_write(goal_speed, 2, spinning)
                await self.bus.sync_write(ct.REGISTERS["torque_enable"].address, 1, energised)
        if any(self.arm.torque[n] is Torque.ON for n in self.arm.names):
            # Torque found on at boot (a previous run died without limping): say so;
            # the command gate stays closed until an operator enables or disables.
            log.warning("arm torque found ON at start-up; commands refused until torque is set")
            for n in self.arm.names:
                self.arm.set_torque_state(n, Torque.UNKNOWN)

    # -- per-tick supervision, heal, auto-home ------------------------------------

    def _after_tick(self, now: float) -> None:
        assert self.loop is not None
        bits = {g.name: self.loop.readings[g.id].error for g in self.geometry.values()}
        self.stalls.update(now, self.arm.measured, bits)

    def _on_stall(self, event: StallEvent) -> None:
        log.warning(
            "STALL %s: %.3f rad from target; %s", event.joint, event.error_rad, event.diagnosis
        )
        self.arm.stalled.add(event.joint)
        if self.arm.traj.stall_reason(event.joint) == "lag":
            # Not keeping up: stop where it is rather than push against what holds it.
            self.arm.hold(event.t)

    async def heal(self) -> HealReport:
        report = await heal(_HealAdapter(self))
        self.last_heal = report
        log.info("heal: %s (%s)", report.result, "; ".join(report.details))
        return report

    async def _boot_heal(self, want_home: bool) -> None:
        report = await self.heal()
        if not want_home:
            return
        if report.result == "unknown":
            self.auto_home_state = "skipped"
            return
        self.auto_home_state = await auto_home(self._wait_seeded, self._park)

    async def _wait_seeded(self, timeout: float) -> bool:
        return await self.wait_ready(timeout)

    async def _park(self) -> None:
        from lupin import api_models as m

        await self.services.set_torque(m.TorqueRequest(enabled=True))
        if not self.arm.gate_open:
            raise RuntimeError("torque did not come on")
        await self.services.go_preset("home")

    async def _watch_resume(self) -> None:
        watcher = ResumeWatcher()
        while True:
            await asyncio.sleep(1.0)
            if watcher.resumed():
                log.warning("resume from suspend detected: re-running heal")
                await self.heal()

    async def wait_torque_on(self, timeout: float) -> bool:
        deadline = asyncio.get_running_loop().time() + timeout
        while not self.arm.gate_open:
            if asyncio.get_running_loop().time() > deadline:
                return False
            await asyncio.sleep(0.01)
        return True

    def mux_sources(self) -> list[str]:
        return [s.name for s in self.mux.sources]

    def pad_layout_info(self) -> dict[str, object] | None:
        return self.pad_info

    def pad_state(self) -> dict[str, object]:
        st = self.pad_status
        if st is None:
            return {"connected": False}
        age = None if st.last_frame_at is None else max(0.0, self.clock() - st.last_frame_at)
        return {
            "connected": st.connected,
            "layout": st.layout,
            "deadman": st.deadman_held,
            "age_s": age,
        }

    # -- the pad ------------------------------------------------------------------

    def prepare_pad(self) -> Callable[[], Any] | None:
        """Resolve layout, mapping and reader now, so a mistake fails before anything moves."""
        spec = self.options.pad
        if spec == "none":
            return None
        try:
            layout = resolve_layout(self.options.pad_layout)
            mapping = load_mapping(layout)
            open_pad(spec, layout=layout)
        except registry.AdapterNotFound as exc:
            if spec == "auto":
                log.warning("no pad reader available (%s); running without a pad", exc)
                return None
            raise PadError(str(exc)) from exc
        except (ConfigError, ValueError) as exc:
            raise PadError(str(exc)) from exc
        self.pad_info = {"layout": layout, "mapping": mapping.model_dump()}
        self.pad_status = PadStatus(layout=layout)
        base = BaseTeleop(mapping)
        windows = {n: g.window_rad for n, g in self.geometry.items()}
        arm_t = ArmTeleop(mapping, self.arm.names, windows, gripper=self.profile.arm.gripper)
        opener = functools.partial(open_pad, spec, layout=layout)

        async def run() -> None:
            await run_pad(
                opener,  # type: ignore[arg-type]
                base,
                arm_t,
                submit_twist=self._pad_submit,
                arm=self.arm,
                clock=self.clock,
                status=self.pad_status,
            )

        return run

    def start_pad(self, run: Callable[[], Any]) -> None:
        """Start reading the pad (after ready: a replay's t counts from this moment)."""
        self._tasks.append(asyncio.create_task(run(), name="pad"))

    def _pad_submit(self, source: str, twist: Twist) -> None:
        # In takeover mode (or a profile without `joy`) the pad feeds `manual`.
        if source not in self.mux_sources():
            source = "manual"
        self.submit_twist(source, twist)

    # -- commands used by the API and teleop -----------------------------------

    def _mux_output(self, now: float) -> tuple[Twist | None, float]:
        out = self.mux.output(now)
        if out.source != self._mux_active:
            # Who drives the base is a state transition an operator reconstructs from the
            # journal ("why did it stop?"): log each change, once (called once per tick).
            log.info(
                "mux: %s drives the base (was %s)%s",
                out.source or "nothing",
                self._mux_active or "nothing",
                f", locked by {out.locked_by}" if out.locked_by else "",
            )
            self._mux_active = out.source
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
        self.arm.hold(self.clock())
        await self.loop.disable_torque()


class _HealAdapter:
    """The daemon as heal sees it: enumerate, re-enable, restart."""

    def __init__(self, daemon: Daemon) -> None:
        self.d = daemon

    async def enumerate(self) -> dict[int, tuple[int, int, int]] | None:
        d = self.d
        if d.bus is None or d.loop is None:
            return None
        mode_addr = ct.REGISTERS["operating_mode"].address
        span = ct.REGISTERS["torque_enable"].address - mode_addr + 1
        try:
            res = await d.bus.sync_read(d.loop.ids, mode_addr, span, priority=1, retries=1)
        except Exception:
            return None
        return {sid: (data[0], data[-1], res.errors.get(sid, 0)) for sid, data in res.data.items()}

    def expected(self) -> dict[int, tuple[str, int, bool]]:
        d = self.d
        out = {
            g.id: (g.name, int(MODE_POSITION), d.arm.torque[g.name] is Torque.ON)
            for g in d.geometry.values()
        }
        if d.base is not None and d.loop is not None:
            for w in d.base.config.wheels:
                out[w.id] = (w.name, int(MODE_VELOCITY), d.loop.wheel_torque)
        return out

    async def reenable(self, servo_id: int) -> bool:
        d = self.d
        assert d.loop is not None
        ok = await d.loop.reenable(servo_id)
        geo = d.loop.by_id.get(servo_id)
        if ok and geo is not None:
            d.arm.stalled.discard(geo.name)
        return ok

    def dead_tasks(self) -> list[str]:
        return list(self.d.restarts)

    async def restart_tasks(self) -> list[str]:
        # Crashed tasks restart themselves with backoff (Daemon._spawn); report them once.
        done, self.d.restarts = self.d.restarts, []
        return done


__all__ = ["BusOpenError", "Daemon", "DaemonOptions", "PadError", "build_mux"]
