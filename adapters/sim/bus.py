"""The simulated Feetech bus: servos by id, answering instruction packets as real ones do.

``SimulatedBus.handle(packet, now)`` is the whole protocol: it advances every
servo's physics to ``now``, applies the instruction and returns the status
packets the servos would put on the wire. It knows nothing about ptys or time
passing by itself, so tests can drive it directly with a fake clock; the pty
server (``pty_server.py``) wraps it for the real serial path.

Everything received is logged with its timestamp (``received``), so a test can
assert on the daemon's bus traffic: ``writes_to(42, since=t)`` is "which goals
were written since t", and an idle robot must produce none.
"""

from __future__ import annotations

import math
import random
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from lupin import control_table as ct
from lupin.protocol import BROADCAST_ID, Instruction, Packet, status
from lupin_adapters.sim.faults import Fault, Reply, apply_faults, make_fault
from lupin_adapters.sim.servo import SimServo

_WRITES = (Instruction.WRITE, Instruction.REG_WRITE)


@dataclass(frozen=True)
class WriteRecord:
    """One register write as received (a SYNC_WRITE yields one per servo)."""

    t: float
    id: int  # BROADCAST_ID for a broadcast WRITE
    instruction: Instruction
    address: int
    data: bytes

    def value(self, name: str) -> int | None:
        """The named register's value in this write, or None if the write does not cover it."""
        reg = ct.REGISTERS[name]
        start = reg.address - self.address
        if start < 0 or start + reg.size > len(self.data):
            return None
        return ct.decode_value(reg, self.data[start : start + reg.size])


class SimulatedBus:
    """A set of SimServos on one line. Not thread-safe: one owner (an event loop) drives it."""

    def __init__(
        self, servos: Iterable[SimServo] = (), *, seed: int | None = 0, log_size: int = 10_000
    ) -> None:
        self.servos: list[SimServo] = list(servos)
        self.dead: set[int] = set()
        self.faults: list[Fault] = []
        self.rng = random.Random(seed)
        self.received: deque[tuple[float, Packet]] = deque(maxlen=log_size)
        self._now: float | None = None

    # -- the servos ---------------------------------------------------------------

    def add(self, servo: SimServo) -> None:
        self.servos.append(servo)

    def servo(self, id: int) -> SimServo:
        """The servo answering to ``id`` now (its id register can be rewritten)."""
        for s in self.servos:
            if s.id == id:
                return s
        raise KeyError(f"no simulated servo with id {id}")

    def __getitem__(self, id: int) -> SimServo:
        return self.servo(id)

    @property
    def ids(self) -> list[int]:
        return [s.id for s in self.servos]

    def _alive(self, id: int) -> list[SimServo]:
        # A list: two servos sharing an id both answer, as they would collide on a real line.
        if id == BROADCAST_ID:
            return [s for s in self.servos if s.id not in self.dead]
        return [s for s in self.servos if s.id == id and id not in self.dead]

    def advance(self, now: float) -> None:
        """Run every servo's physics up to ``now`` (time never runs backwards)."""
        if self._now is not None and now > self._now:
            for s in self.servos:
                s.step(now - self._now)
        if self._now is None or now > self._now:
            self._now = now

    def sync_clock(self, now: float) -> None:
        """Count time from ``now`` on without simulating the gap (a new clock took over)."""
        self._now = now

    # -- fault injection -------------------------------------------------------------

    def inject(
        self,
        kind: str,
        *,
        ids: Iterable[int] | None = None,
        rate: float = 1.0,
        count: int | None = None,
        seconds: float | None = None,
    ) -> Fault:
        """Add a reply fault (see ``faults.py`` for the kinds); returns it for inspection."""
        fault = make_fault(kind, ids=ids, rate=rate, count=count, seconds=seconds)
        self.faults.append(fault)
        return fault

    def clear_faults(self) -> None:
        self.faults.clear()

    def kill(self, id: int) -> None:
        """The servo stops answering and acting (unplugged, browned out)."""
        self.dead.add(id)

    def revive(self, id: int) -> None:
        self.dead.discard(id)

    def set_error(self, id: int, bits: int) -> None:
        self.servo(id).force_error(bits)

    def latch(self, id: int) -> None:
        self.servo(id).latch()

    # -- the log ---------------------------------------------------------------

    def clear_log(self) -> None:
        self.received.clear()

    def instructions(self, code: int, *, since: float = -math.inf) -> list[tuple[float, Packet]]:
        return [(t, p) for t, p in self.received if p.code == code and t >= since]

    def writes(self, *, since: float = -math.inf) -> list[WriteRecord]:
        """Every WRITE, REG_WRITE and SYNC_WRITE received since ``since``, one record per servo."""
        out: list[WriteRecord] = []
        for t, p in self.received:
            if t < since or len(p.params) < 2:
                continue
            if p.code in _WRITES:
                out.append(WriteRecord(t, p.id, Instruction(p.code), p.params[0], p.params[1:]))
            elif p.code == Instruction.SYNC_WRITE:
                out += [
                    WriteRecord(t, sid, Instruction.SYNC_WRITE, p.params[0], data)
                    for sid, data in _sync_entries(p.params)
                ]
        return out

    def writes_to(
        self, address: int, *, since: float = -math.inf, id: int | None = None
    ) -> list[WriteRecord]:
        """The writes whose span covers ``address`` (optionally to one servo id)."""
        return [
            w
            for w in self.writes(since=since)
            if w.address <= address < w.address + len(w.data) and (id is None or w.id == id)
        ]

    # -- the protocol -------------------------------------------------------------

    def handle(self, packet: Packet, now: float) -> list[bytes]:
        """The status packets answering ``packet`` (delay faults are ignored here)."""
        return [r.data for r in self.respond(packet, now)]

    def respond(self, packet: Packet, now: float) -> list[Reply]:
        """Like ``handle``, keeping each reply's extra delay for a timed transport."""
        self.advance(now)
        self.received.append((now, packet))
        out: list[Reply] = []
        for servo, data in self._execute(packet):
            reply = apply_faults(self.faults, Reply(servo.id, data), self.rng)
            if reply is not None:
                out.append(reply)
        self.faults = [f for f in self.faults if f.count != 0]
        return out

    def _execute(self, p: Packet) -> list[tuple[SimServo, bytes]]:
        """Apply one instruction; the (servo, status packet) pairs it answers with."""
        answers: list[tuple[SimServo, bytes]] = []

        def answer(s: SimServo, params: bytes = b"", *, always: bool = False) -> None:
            # status_return_level 0: only PING and READ are answered.
            if p.id != BROADCAST_ID and (always or s.get("status_return_level") != 0):
                answers.append((s, status(s.id, int(s.error), params)))

        code, params = p.code, p.params
        if code == Instruction.SYNC_READ:
            if len(params) >= 3:
                for sid in params[2:]:  # listed order; the missing stay silent
                    for s in self._alive(sid):
                        answers.append((s, status(s.id, int(s.error), s.read(*params[:2]))))
            return answers
        if code == Instruction.SYNC_WRITE:
            if len(params) >= 2:
                for sid, data in _sync_entries(params):
                    for s in self._alive(sid):
                        s.write(params[0], data)
            return answers  # never answered
        for s in self._alive(p.id):
            if code == Instruction.PING:
                answer(s, always=True)
            elif code == Instruction.READ and len(params) == 2:
                answer(s, s.read(params[0], params[1]), always=True)
            elif code == Instruction.WRITE and len(params) >= 2:
                s.write(params[0], params[1:])
                answer(s)
            elif code == Instruction.REG_WRITE and len(params) >= 2:
                s.reg_write(params[0], params[1:])
                answer(s)
            elif code == Instruction.ACTION:
                s.action()
                answer(s)
            # Anything else (unknown instruction, malformed params) goes unanswered.
        return answers


def _sync_entries(params: bytes) -> list[tuple[int, bytes]]:
    """(id, data) pairs of a SYNC_WRITE; a short trailing entry is ignored, as by the servos."""
    length = params[1]
    body = params[2:]
    step = length + 1
    return [
        (body[i], bytes(body[i + 1 : i + step]))
        for i in range(0, len(body) - step + 1, step)
        if length > 0
    ]


@dataclass(frozen=True)
class SimServoSpec:
    """What a robot profile says about one simulated servo."""

    id: int
    mode: int = ct.OperatingMode.POSITION  # 0 position, 1 velocity
    position: float = 2048  # initial present position, counts
    gravity: float = 0.0  # holding load (per mille) pulling toward lower counts
    sag_rate: float = 0.0  # counts/s a limp joint falls toward its stop; 0 = stays put
    min_limit: int = 0
    max_limit: int = 4095
    p_gain: int = 32  # the STS3215 default; the SO-101 shipped with 16, the seed applied 64
    rest: float | None = None  # where a limp joint sags to; None = the stop gravity pulls to


def build_sim_bus(servos: Sequence[SimServoSpec], *, seed: int | None = 0) -> SimulatedBus:
    """A bus holding one SimServo per spec."""
    return SimulatedBus(
        (
            SimServo(
                s.id,
                mode=s.mode,
                position=s.position,
                gravity=s.gravity,
                sag_rate=s.sag_rate,
                min_limit=s.min_limit,
                max_limit=s.max_limit,
                p_gain=s.p_gain,
                rest=s.rest,
            )
            for s in servos
        ),
        seed=seed,
    )
