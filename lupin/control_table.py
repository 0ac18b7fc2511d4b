"""The STS3215 control table as data, and the codec for register values.

Addresses and sizes agree with LeRobot's ``STS_SMS_SERIES_CONTROL_TABLE``
(``lerobot/motors/feetech/tables.py``), which cites Feetech's STS/SMS manual.
Sign bits: homing_offset (11), goal_speed and present_speed (15) agree with
LeRobot's encoding table; goal_position, present_position (15), present_load
(10) and present_current (15) are taken from Feetech's own SMS_STS reference
code (WritePosEx / ReadPos / ReadLoad / ReadCurrent), which LeRobot omits.
present_current's sign bit is not in our spec; it only matters if bit 15 is
ever set, and then Feetech's reading is the one to trust.

Negative values are sign-magnitude, not two's complement: the magnitude sits in
the low bits and one "direction" bit marks negatives. Writing -1 as 0xFFFF
would read back on the servo as -32767, so nothing here ever wraps.
"""

from __future__ import annotations

import operator
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import IntEnum
from types import MappingProxyType

# Below this address the table lives in EEPROM: writes need lock (55) = 0 first
# and wear the flash, so tools write there only on purpose.
EEPROM_END = 40


class OperatingMode(IntEnum):
    POSITION = 0
    VELOCITY = 1  # "wheel" mode: goal_speed is obeyed, goal_position ignored


class TorqueEnable(IntEnum):
    OFF = 0
    ON = 1
    # Makes the present position read 2048 by rewriting homing_offset (EEPROM).
    RECENTRE = 128


@dataclass(frozen=True, slots=True)
class Register:
    name: str
    address: int
    size: int  # bytes: 1 or 2
    eeprom: bool
    readonly: bool
    sign_bit: int | None = None

    @property
    def value_range(self) -> tuple[int, int]:
        """The values ``encode_value`` accepts."""
        if self.sign_bit is None:
            return 0, (1 << (8 * self.size)) - 1
        top = (1 << self.sign_bit) - 1
        return -top, top


def _table(*rows: tuple[str, int, int, bool, int | None]) -> Mapping[str, Register]:
    regs = {
        name: Register(name, addr, size, addr < EEPROM_END, ro, sign)
        for name, addr, size, ro, sign in rows
    }
    return MappingProxyType(regs)


RO, RW = True, False

# name, address, size, read-only, sign bit
REGISTERS: Mapping[str, Register] = _table(
    ("firmware_major", 0, 1, RO, None),
    ("firmware_minor", 1, 1, RO, None),
    ("model", 3, 2, RO, None),  # 777 for an STS3215
    ("id", 5, 1, RW, None),
    ("baud_rate", 6, 1, RW, None),  # an index: 0 = 1 Mbaud, 1 = 500 k, ...
    ("return_delay", 7, 1, RW, None),  # units of 2 µs
    ("status_return_level", 8, 1, RW, None),
    ("min_position_limit", 9, 2, RW, None),
    ("max_position_limit", 11, 2, RW, None),
    ("max_temperature_limit", 13, 1, RW, None),
    ("max_voltage_limit", 14, 1, RW, None),
    ("min_voltage_limit", 15, 1, RW, None),
    ("max_torque_limit", 16, 2, RW, None),
    ("p_coefficient", 21, 1, RW, None),
    ("d_coefficient", 22, 1, RW, None),
    ("i_coefficient", 23, 1, RW, None),
    ("homing_offset", 31, 2, RW, 11),  # ±2047; present = actual - offset (mod 4096)
    ("operating_mode", 33, 1, RW, None),
    ("torque_enable", 40, 1, RW, None),
    ("acceleration", 41, 1, RW, None),
    ("goal_position", 42, 2, RW, 15),
    ("goal_time", 44, 2, RW, None),
    ("goal_speed", 46, 2, RW, 15),
    ("torque_limit", 48, 2, RW, None),
    ("lock", 55, 1, RW, None),  # 0 unlocks EEPROM writes; RAM itself
    ("present_position", 56, 2, RO, 15),
    ("present_speed", 58, 2, RO, 15),
    ("present_load", 60, 2, RO, 10),
    ("present_voltage", 62, 1, RO, None),  # units of 0.1 V
    ("present_temperature", 63, 1, RO, None),  # °C
    ("status", 65, 1, RO, None),
    ("moving", 66, 1, RO, None),
    ("present_current", 69, 2, RO, 15),
)

_BY_ADDRESS: Mapping[int, Register] = MappingProxyType({r.address: r for r in REGISTERS.values()})


def by_address(address: int) -> Register:
    """The register starting at ``address``; KeyError if none starts there."""
    try:
        return _BY_ADDRESS[address]
    except KeyError:
        raise KeyError(f"no register starts at address {address}") from None


def encode_value(reg: Register, value: int) -> bytes:
    """``value`` as the bytes to write to ``reg``; ValueError if it does not fit.

    Read-only registers are encoded too: the simulated servo builds its
    replies with this. Refusing writes to them is the bus user's job.
    """
    value = operator.index(value)  # refuses floats and other non-integers
    lo, hi = reg.value_range
    if not lo <= value <= hi:
        raise ValueError(f"{reg.name}: {value} is out of range {lo}..{hi}")
    raw = value
    if reg.sign_bit is not None and value < 0:
        raw = -value | (1 << reg.sign_bit)
    return raw.to_bytes(reg.size, "little")


def decode_value(reg: Register, data: bytes | bytearray | memoryview) -> int:
    """The inverse of ``encode_value``; ValueError unless ``data`` is ``reg.size`` bytes.

    With the sign bit set, the result is minus the rest of the word, exactly as
    the vendor's SCS_TOHOST does: bits above the sign bit (never set by a
    healthy servo) stay in the magnitude rather than vanishing silently, and a
    "negative zero" reads 0.
    """
    if len(data) != reg.size:
        raise ValueError(f"{reg.name}: expected {reg.size} bytes, got {len(data)}")
    raw = int.from_bytes(data, "little")
    if reg.sign_bit is not None and raw & (1 << reg.sign_bit):
        return -(raw & ~(1 << reg.sign_bit))
    return raw


def decode_block(
    start_address: int, data: bytes | bytearray | memoryview, names: Iterable[str]
) -> dict[str, int]:
    """Pull the named registers out of one contiguous read starting at ``start_address``.

    KeyError for an unknown name; ValueError if a register is not wholly inside
    the block (a short reply is a failed read, not a partial one).
    """
    out: dict[str, int] = {}
    for name in names:
        reg = REGISTERS[name]
        offset = reg.address - start_address
        if offset < 0 or offset + reg.size > len(data):
            raise ValueError(
                f"{reg.name} (address {reg.address}, {reg.size} bytes) is not inside the "
                f"{len(data)}-byte block read from address {start_address}"
            )
        out[name] = decode_value(reg, data[offset : offset + reg.size])
    return out
