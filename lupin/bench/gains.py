"""Servo P/D/I gains against the profile: ``lupin gains show`` and ``apply``.

Gains live in servo EEPROM, so they are invisible configuration that a servo
swap silently reverts; the profile is the source of truth and these reconcile
the hardware with it (bring-up seed). ``apply`` reports success only on a
double read-back that agrees (see ``registers.py`` for why).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from lupin.bench.registers import EepromWriteFailed, ServoIO
from lupin.config_models import Gains, JointConfig

GAIN_REGISTERS = ("p_coefficient", "d_coefficient", "i_coefficient")


@dataclass(frozen=True)
class ServoGains:
    p: int
    d: int
    i: int

    @classmethod
    def from_registers(cls, regs: dict[str, int]) -> ServoGains:
        return cls(regs["p_coefficient"], regs["d_coefficient"], regs["i_coefficient"])

    @classmethod
    def from_profile(cls, gains: Gains) -> ServoGains:
        return cls(gains.p, gains.d, gains.i)

    def registers(self) -> dict[str, int]:
        return {"p_coefficient": self.p, "d_coefficient": self.d, "i_coefficient": self.i}

    def __str__(self) -> str:
        return f"P={self.p} D={self.d} I={self.i}"


@dataclass(frozen=True)
class GainRow:
    name: str
    id: int
    want: ServoGains
    have: ServoGains | None  # None: no confirmed read

    @property
    def matches(self) -> bool:
        return self.have == self.want


@dataclass(frozen=True)
class ApplyResult:
    name: str
    id: int
    want: ServoGains
    ok: bool
    detail: str


async def read_gains(io: ServoIO, sid: int) -> ServoGains | None:
    got = await io.read_confirmed(sid, GAIN_REGISTERS)
    return None if got is None else ServoGains.from_registers(got)


async def write_gains(io: ServoIO, sid: int, gains: ServoGains) -> ServoGains:
    """Write P/D/I in one EEPROM write; raises EepromWriteFailed unless confirmed."""
    return ServoGains.from_registers(await io.write_eeprom(sid, gains.registers()))


async def compare(io: ServoIO, joints: Sequence[JointConfig]) -> list[GainRow]:
    """Each joint's servo gains beside the profile's. Read-only."""
    return [
        GainRow(j.name, j.id, ServoGains.from_profile(j.gains), await read_gains(io, j.id))
        for j in joints
    ]


async def apply(io: ServoIO, joints: Sequence[JointConfig]) -> list[ApplyResult]:
    """Write the profile's gains to every joint whose servo differs; one result per joint."""
    out = []
    for row in await compare(io, joints):
        if row.matches:
            out.append(ApplyResult(row.name, row.id, row.want, True, "already set"))
            continue
        try:
            await write_gains(io, row.id, row.want)
        except EepromWriteFailed as exc:
            out.append(ApplyResult(row.name, row.id, row.want, False, str(exc)))
        else:
            was = str(row.have) if row.have else "unreadable"
            out.append(ApplyResult(row.name, row.id, row.want, True, f"was {was}, verified"))
    return out
