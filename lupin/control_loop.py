"""The control tick: read every servo, run the controllers, write only what changed.

Each tick is one SYNC_READ of every servo's position, speed and load (health,
round-robin, one servo every few ticks), then the mux, base and arm, then at
most one SYNC_WRITE of the goals that changed since the last write. An idle
robot therefore writes nothing (the bring-up seed's bus budget, beaten: it read
one joint per cycle, this reads all of them every tick).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from lupin import control_table as ct
from lupin.arm import ArmCommander, Torque
from lupin.base import BaseDrive
from lupin.bus import PRIORITY_CONTROL, ServoBus
from lupin.joints import JointGeometry
from lupin.logs import Throttled
from lupin.mux import Twist
from lupin.protocol import ServoError

log = logging.getLogger(__name__)

REG = ct.REGISTERS
STATE_ADDR = REG["present_position"].address  # 56: position, speed, load
STATE_LEN = 6
HEALTH_ADDR = REG["present_voltage"].address  # 62: voltage, temperature, (63..65) status
HEALTH_LEN = 4
GOAL_POS = REG["goal_position"]
GOAL_SPEED = REG["goal_speed"]
TORQUE = REG["torque_enable"].address
# Consecutive missed reads after which a servo counts as lost (0.1 s at 100 Hz): logged,
# and a lost wheel stops the base. A 20 % noisy line misses 10 in a row about once in 10^7.
LOST_TICKS = 10
# The fastest an arm joint's reading can honestly move: one turn a second, above the
# STS3215's no-load speed (~0.75 rev/s). A status packet's checksum is one byte, so a
# reply cut short on a noisy line and completed by the next servo's bytes passes it
# about once in 256: a well-formed reading of garbage. Adopted as measurement, resync
# sent it back as a goal and the joint lurched toward its limit (found by the
# reliability suite). A reading that jumps further than this from the last one is held
# until the next reading confirms it; until then the joint counts as not answering.
MAX_COUNTS_PER_S = 4096.0
JUMP_SLACK_COUNTS = 8  # reading noise and tick jitter on top of the speed bound
BUS_REPORT_S = 5.0  # bus failures are summarised in the log at most this often


@dataclass
class ServoReading:
    position: int = 0
    speed: int = 0
    load: int = 0
    t: float = 0.0  # when last read (monotonic)
    voltage_v: float | None = None
    temperature_c: int | None = None
    status: int = 0
    error: int = 0  # status packet error byte
    misses: int = 0  # consecutive ticks without an answer
    suspect: tuple[int, float] | None = None  # an implausible jump awaiting confirmation


@dataclass
class TickStats:
    """Tick timing for /metrics and the benchmarks."""

    periods: deque[float] = field(default_factory=lambda: deque(maxlen=2000))
    durations: deque[float] = field(default_factory=lambda: deque(maxlen=2000))
    ticks: int = 0
    overruns: int = 0
    writes: int = 0
    last_tick: float = 0.0


class ControlLoop:
    def __init__(
        self,
        bus: ServoBus,
        arm: ArmCommander,
        arm_joints: dict[str, JointGeometry],
        base: BaseDrive | None,
        mux_output: Callable[[float], tuple[Twist | None, float]],
        *,
        tick_hz: float = 100.0,
        health_every: int = 10,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.bus = bus
        self.arm = arm
        self.arm_joints = arm_joints
        self.by_id = {g.id: g for g in arm_joints.values()}
        self.base = base
        self.mux_output = mux_output
        self.period = 1.0 / tick_hz
        self.health_every = health_every
        self.clock = clock
        self.ids = [g.id for g in arm_joints.values()] + (base.wheel_ids if base else [])
        self.names = {g.id: g.name for g in arm_joints.values()}
        if base is not None:
            self.names |= {w.id: f"wheel {w.name}" for w in base.config.wheels}
        self.readings: dict[int, ServoReading] = {i: ServoReading() for i in self.ids}
        self.stats = TickStats()
        self.estop = False
        self.wheels_excluded: dict[int, str] = {}
        self._written_pos: dict[int, int] = {}
        self._written_speed: dict[int, int] = {}
        self._wheel_torque = False
        self._health_cursor = 0
        self._enable_queue: list[str] = []
        self._stop = asyncio.Event()
        self.first_state = asyncio.Event()
        self.on_tick: list[Callable[[float], None]] = []
        self.on_state: list[Callable[[float], None]] = []  # right after the measurement
        self._throttled = Throttled(log)
        self._blocked: str | None = None  # why the base refuses to drive, as last logged
        self._resend: set[int] = set()  # wheels back from an outage: send their goal again
        self._failures_seen = 0
        self._failures_logged: dict[str, int] = {}
        self._next_bus_report = -float("inf")

    # -- torque requests (served one joint per tick) ------------------------------

    def request_enable(self) -> None:
        for name in self.arm.names:
            if name not in self.arm.excluded and self.arm.torque[name] is not Torque.ON:
                self.arm.set_torque_state(name, Torque.ENABLING)
                if name not in self._enable_queue:
                    self._enable_queue.append(name)

    async def disable_torque(self) -> None:
        """Close the command gate first, then cut torque at once (two-gate sequence)."""
        self.arm.gate_open = False
        self._enable_queue.clear()
        ids = [g.id for g in self.arm_joints.values()]
        await self.bus.sync_write(TORQUE, 1, {i: b"\x00" for i in ids}, priority=PRIORITY_CONTROL)
        for name in self.arm.names:
            self.arm.set_torque_state(name, Torque.OFF)
        self._written_pos.clear()
        log.info("arm torque off; command gate closed")

    async def _enable_step(self) -> None:
        name = self._enable_queue[0]
        geo = self.arm_joints[name]
        reading = self.readings[geo.id]
        if reading.misses or reading.t == 0.0:
            return  # a joint whose position cannot be read stays limp
        # Seed the goal register with the present position, then energise: the
        # order that stops an arm snapping to a stale goal (bring-up seed).
        pos = reading.position
        goal = ct.encode_value(GOAL_POS, pos)
        ok = await self.bus.write(geo.id, GOAL_POS.address, goal, priority=PRIORITY_CONTROL)
        ok = ok and await self.bus.write(geo.id, TORQUE, b"\x01", priority=PRIORITY_CONTROL)
        if not ok:
            log.warning("torque enable on %s got no acknowledgement; will retry", name)
            return
        self._enable_queue.pop(0)
        self._written_pos[geo.id] = pos
        self.arm.pin_to_measured([name])
        self.arm.set_torque_state(name, Torque.ON)
        if not self._enable_queue:
            self.arm.gate_open = True
            log.info("arm torque on; command gate open")

    @property
    def wheel_torque(self) -> bool:
        return self._wheel_torque

    async def reenable(self, servo_id: int) -> bool:
        """Re-energise one servo that unloaded (heal): seed its goal first, as at enable."""
        reading = self.readings.get(servo_id)
        if reading is None or reading.misses or reading.t == 0.0:
            return False
        geo = self.by_id.get(servo_id)
        if geo is not None:
            goal_reg, value = GOAL_POS, reading.position
        else:
            goal_reg, value = GOAL_SPEED, 0
        data = ct.encode_value(goal_reg, value)
        ok = await self.bus.write(servo_id, goal_reg.address, data, priority=PRIORITY_CONTROL)
        ok = ok and await self.bus.write(servo_id, TORQUE, b"\x01", priority=PRIORITY_CONTROL)
        if ok and geo is not None:
            self._written_pos[servo_id] = value
            self.arm.pin_to_measured([geo.name])
        elif ok:
            self._written_speed[servo_id] = 0
        return ok

    # -- the tick ----------------------------------------------------------------------

    async def run(self) -> None:
        loop = asyncio.get_running_loop()
        next_at = loop.time()
        last_start: float | None = None
        while not self._stop.is_set():
            start = loop.time()
            if last_start is not None:
                self.stats.periods.append(start - last_start)
            last_start = start
            try:
                await self.tick()
            except Exception:
                self._throttled.exception("tick", "control tick failed", start)
            self.stats.durations.append(loop.time() - start)
            next_at += self.period
            delay = next_at - loop.time()
            if delay < 0:
                self.stats.overruns += 1
                next_at = loop.time()  # do not try to catch up with a burst of ticks
                delay = 0
            # A plain sleep: at most one tick of stop latency, and no task per tick.
            await asyncio.sleep(delay)

    def stop(self) -> None:
        self._stop.set()

    async def tick(self) -> None:
        result = await self.bus.sync_read(self.ids, STATE_ADDR, STATE_LEN)
        now = self.clock()
        self.stats.ticks += 1
        self.stats.last_tick = now
        measured = {}
        for sid in self.ids:
            r = self.readings[sid]
            data = result.data.get(sid)
            if data is None:
                r.misses += 1
                if r.misses == LOST_TICKS:
                    log.warning(
                        "%s (id %d) not answering: %d reads missed", *self._who(sid), LOST_TICKS
                    )
                continue
            position = ct.decode_value(REG["present_position"], data[0:2])
            if sid in self.by_id and not self._plausible(r, position, now):
                r.misses += 1
                continue
            if r.misses >= LOST_TICKS:
                log.info(
                    "%s (id %d) answering again after %d missed reads", *self._who(sid), r.misses
                )
                if sid not in self.by_id:
                    self._resend.add(sid)  # it may have missed a goal (a stop) while away
            r.position = position
            r.speed = ct.decode_value(REG["present_speed"], data[2:4])
            r.load = ct.decode_value(REG["present_load"], data[4:6])
            error = result.errors.get(sid, 0)
            if error != r.error:
                self._log_error_bits(sid, error)
            r.error = error
            r.t, r.misses = now, 0
            geo = self.by_id.get(sid)
            if geo is not None:
                measured[geo.name] = geo.counts_to_rad(r.position)
        self.arm.observe(measured, now)
        # Before any await: whoever reads state mid-tick sees status and events agree.
        for callback in self.on_state:
            callback(now)
        if measured and len(measured) == len(self.arm_joints):
            self.first_state.set()
        if self._enable_queue:
            await self._enable_step()
        await self._write_goals(now)
        if self.stats.ticks % self.health_every == 0:
            await self._read_health()
        self._report_bus(now)
        for callback in self.on_tick:
            callback(now)

    def _plausible(self, r: ServoReading, position: int, now: float) -> bool:
        """False for an arm reading that jumped further than the joint can move (see
        MAX_COUNTS_PER_S), until a second reading confirms the new place."""
        if r.t == 0.0:
            return True  # the first reading: nothing to compare with

        def reach(since: float) -> float:
            return MAX_COUNTS_PER_S * max(0.0, now - since) + JUMP_SLACK_COUNTS

        if abs(position - r.position) <= reach(r.t):
            r.suspect = None
            return True
        if r.suspect is not None and abs(position - r.suspect[0]) <= reach(r.suspect[1]):
            r.suspect = None  # two readings agree: the joint really is there
            return True
        r.suspect = (position, now)
        self.bus.stats.fail("implausible")
        return False

    # -- reporting ---------------------------------------------------------------------

    def _who(self, sid: int) -> tuple[str, int]:
        return self.names.get(sid, "servo"), sid

    def _log_error_bits(self, sid: int, error: int) -> None:
        if error:
            bits = ServoError(error)
            causes = ", ".join(b.name.lower() for b in ServoError if b in bits and b.name)
            log.warning("%s (id %d) reports %s (error bits %d)", *self._who(sid), causes, error)
        else:
            log.info("%s (id %d): error bits cleared", *self._who(sid))

    def _report_bus(self, now: float) -> None:
        """Summarise new bus failures in the log: the first at once, then every few seconds."""
        failures = self.bus.stats.failures
        total = sum(failures.values())
        if total == self._failures_seen or now < self._next_bus_report:
            return
        self._failures_seen = total
        self._next_bus_report = now + BUS_REPORT_S
        new = {k: n - self._failures_logged.get(k, 0) for k, n in failures.items()}
        self._failures_logged = dict(failures)
        lost = [sid for sid, r in self.readings.items() if r.misses]
        log.warning(
            "servo bus: failures since the last report: %s; missing this tick: %s",
            ", ".join(f"{k} {n}" for k, n in sorted(new.items()) if n) or "none",
            lost or "none",
        )

    def base_blocked(self) -> str | None:
        """Why the base refuses to drive, or None.

        One wheel of a differential (or mecanum) base cannot drive it: it spins the
        robot instead. So while any wheel is excluded or lost, every wheel gets zero.
        """
        if self.base is None:
            return None
        why = [
            f"{self.names[sid]} (id {sid}) excluded: {self.wheels_excluded[sid]}"
            for sid in self.base.wheel_ids
            if sid in self.wheels_excluded
        ]
        why += [
            f"{self.names[sid]} (id {sid}) not answering"
            for sid in self.base.wheel_ids
            if sid not in self.wheels_excluded and self.readings[sid].misses >= LOST_TICKS
        ]
        return "; ".join(why) or None

    async def _write_goals(self, now: float) -> None:
        pos_goals: dict[int, int] = {}
        for name, rad in self.arm.goals(now).items():
            geo = self.arm_joints[name]
            counts = geo.rad_to_counts(rad)
            if self._written_pos.get(geo.id) != counts:
                pos_goals[geo.id] = counts
        speed_goals: dict[int, int] = {}
        if self.base is not None:
            blocked = self.base_blocked()
            if blocked != self._blocked:
                if blocked:
                    log.warning("base will not drive: %s", blocked)
                else:
                    log.info("base may drive again: every wheel answers")
                self._blocked = blocked
            twist, stamp = self.mux_output(now)
            if self.estop or blocked:
                self.base.stop()
            else:
                self.base.command(twist, stamp)
            for sid, speed in self.base.wheel_goals(now).items():
                if sid in self.wheels_excluded:
                    continue
                resend = sid in self._resend and self._wheel_torque
                self._resend.discard(sid)
                if resend or self._written_speed.get(sid, 0) != speed:
                    speed_goals[sid] = speed
            if speed_goals and not self._wheel_torque and any(speed_goals.values()):
                await self._wheel_torque_on()
        await self._send(pos_goals, speed_goals)

    async def _wheel_torque_on(self) -> None:
        # Wheels stay limp until first asked to move; zero speed goes in before torque.
        ids = [i for i in self.base.wheel_ids if i not in self.wheels_excluded] if self.base else []
        zero = ct.encode_value(GOAL_SPEED, 0)
        await self.bus.sync_write(GOAL_SPEED.address, 2, {i: zero for i in ids})
        await self.bus.sync_write(TORQUE, 1, {i: b"\x01" for i in ids})
        self._wheel_torque = True
        log.info("wheel torque on (speed zeroed first): %s", [self.names[i] for i in ids])

    async def _send(self, pos: dict[int, int], speed: dict[int, int]) -> None:
        if not pos and not speed:
            return
        if pos and speed:
            # One packet for both: goal position, goal time and goal speed are contiguous.
            data = {}
            for sid in pos.keys() | speed.keys():
                p = pos.get(sid, self._written_pos.get(sid, self.readings[sid].position))
                s = speed.get(sid, self._written_speed.get(sid, 0))
                data[sid] = (
                    ct.encode_value(GOAL_POS, p) + b"\x00\x00" + ct.encode_value(GOAL_SPEED, s)
                )
            await self.bus.sync_write(GOAL_POS.address, 6, data)
        elif pos:
            enc = {sid: ct.encode_value(GOAL_POS, p) for sid, p in pos.items()}
            await self.bus.sync_write(GOAL_POS.address, 2, enc)
        else:
            enc = {sid: ct.encode_value(GOAL_SPEED, s) for sid, s in speed.items()}
            await self.bus.sync_write(GOAL_SPEED.address, 2, enc)
        self.stats.writes += 1
        self._written_pos.update(pos)
        self._written_speed.update(speed)

    async def _read_health(self) -> None:
        sid = self.ids[self._health_cursor % len(self.ids)]
        self._health_cursor += 1
        data = await self.bus.read(sid, HEALTH_ADDR, HEALTH_LEN, priority=PRIORITY_CONTROL)
        if data is None:
            return
        r = self.readings[sid]
        r.voltage_v = data[0] / 10
        r.temperature_c = data[1]
        r.status = data[3]

    # -- shutdown ----------------------------------------------------------------------

    async def safe_stop(self) -> None:
        """Zero the wheels and limp every servo: the shutdown and crash-exit sequence."""
        self.arm.gate_open = False
        if self.base is not None:
            zero = ct.encode_value(GOAL_SPEED, 0)
            await self.bus.sync_write(
                GOAL_SPEED.address, 2, dict.fromkeys(self.base.wheel_ids, zero)
            )
        await self.bus.sync_write(TORQUE, 1, dict.fromkeys(self.ids, b"\x00"))
        for name in self.arm.names:
            self.arm.set_torque_state(name, Torque.OFF)
