"""Named register access for the bench tools, and EEPROM writes believed only when verified.

Registers below address 40 live in EEPROM: a write lands only while lock (55)
is 0, and it persists across power cycles, so every EEPROM write here unlocks,
writes, relocks, and then confirms by read-back.

The read-back is read twice and trusted only when both reads agree: an EEPROM
read-back races the relock, and a single read taken too soon returned a garbled
value (observed: 250) that made a successful write look failed (bring-up seed).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from lupin import control_table as ct
from lupin.bus import PRIORITY_SERVICE, ServoBus

REG = ct.REGISTERS
LOCK = REG["lock"]
# Enough reads for two consecutive ones to agree even if one or two are garbled.
CONFIRM_ATTEMPTS = 5


class EepromWriteFailed(Exception):
    """An EEPROM write could not be confirmed; the message names the servo and registers."""


@dataclass(frozen=True)
class Span:
    """A contiguous run of registers read in one READ."""

    start: int
    length: int

    @classmethod
    def covering(cls, names: Sequence[str]) -> Span:
        regs = [REG[n] for n in names]
        start = min(r.address for r in regs)
        end = max(r.address + r.size for r in regs)
        return cls(start, end - start)


class ServoIO:
    """Typed, named register access over a :class:`ServoBus` (service priority)."""

    def __init__(self, bus: ServoBus) -> None:
        self.bus = bus

    async def ping(self, sid: int) -> bool:
        return await self.bus.ping(sid)

    async def read(self, sid: int, name: str) -> int | None:
        """One register, or None when the servo gave no valid reply."""
        values = await self.read_many(sid, (name,))
        return None if values is None else values[name]

    async def read_many(self, sid: int, names: Sequence[str]) -> dict[str, int] | None:
        """Several registers in one READ spanning them all; None on no valid reply."""
        span = Span.covering(names)
        data = await self.bus.read(sid, span.start, span.length, priority=PRIORITY_SERVICE)
        if data is None:
            return None
        return ct.decode_block(span.start, data, names)

    async def read_confirmed(self, sid: int, names: Sequence[str]) -> dict[str, int] | None:
        """Read until two consecutive reads agree; None if they never do."""
        previous: dict[str, int] | None = None
        for _ in range(CONFIRM_ATTEMPTS):
            current = await self.read_many(sid, names)
            if current is not None and current == previous:
                return current
            previous = current
        return None

    async def write(self, sid: int, name: str, value: int) -> bool:
        """Write one register and wait for the servo's acknowledgement."""
        reg = REG[name]
        return await self.bus.write(sid, reg.address, ct.encode_value(reg, value))

    async def write_block(self, sid: int, values: Mapping[str, int]) -> bool:
        """Write contiguous registers in one WRITE; ValueError if they leave a gap."""
        regs = sorted((REG[n] for n in values), key=lambda r: r.address)
        data = b""
        for reg in regs:
            if reg.address != regs[0].address + len(data):
                raise ValueError(f"registers {sorted(values)} are not contiguous")
            data += ct.encode_value(reg, values[reg.name])
        return await self.bus.write(sid, regs[0].address, data)

    async def set_torque(self, sid: int, on: bool) -> bool:
        value = ct.TorqueEnable.ON if on else ct.TorqueEnable.OFF
        return await self.write(sid, "torque_enable", value)

    async def write_eeprom(self, sid: int, values: Mapping[str, int]) -> dict[str, int]:
        """Unlock, write ``values`` (contiguous), relock, confirm; returns the confirmed values.

        Raises :class:`EepromWriteFailed` naming what failed. The relock is
        attempted whatever happened, so a failure does not leave EEPROM open.
        """
        what = ", ".join(f"{n}={v}" for n, v in values.items())
        try:
            if not await self.write(sid, LOCK.name, 0):
                raise EepromWriteFailed(f"servo {sid}: no reply to the EEPROM unlock")
            if not await self.write_block(sid, values):
                raise EepromWriteFailed(f"servo {sid}: no reply to the write of {what}")
        finally:
            relocked = await self.write(sid, LOCK.name, 1)
        if not relocked:
            raise EepromWriteFailed(f"servo {sid}: wrote {what} but no reply to the relock")
        got = await self.read_confirmed(sid, list(values))
        if got is None:
            raise EepromWriteFailed(f"servo {sid}: wrote {what} but no two read-backs agreed")
        if got != dict(values):
            seen = ", ".join(f"{n}={v}" for n, v in got.items())
            raise EepromWriteFailed(f"servo {sid}: wrote {what} but it reads back {seen}")
        return got
