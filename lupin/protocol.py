"""The Feetech (SCS/STS) serial packet codec: bytes in, bytes out, no I/O.

Every packet on the wire, instruction or status, has one shape::

    FF FF  ID  LEN  CODE  P0 .. Pn  CHK      LEN = n + 2 (CODE and CHK)
                                             CHK = ~(ID + LEN + CODE + ΣP) & 0xFF

CODE is the instruction in a packet to a servo and the error byte in a
servo's status reply. Multi-byte register values are little-endian (the SDK's
``PacketHandler(0)``).

The builders return ready-to-send ``bytes`` and refuse (``ValueError``) what no
servo could parse. ``decode`` is the inverse for a stream: it never raises, so
a burst of line noise costs packets, never the task that reads the port.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import IntEnum, IntFlag

__all__ = [
    "BROADCAST_ID",
    "Instruction",
    "Packet",
    "ServoError",
    "action",
    "checksum",
    "decode",
    "ping",
    "read",
    "reg_write",
    "status",
    "sync_read",
    "sync_write",
    "write",
]

HEADER = b"\xff\xff"
BROADCAST_ID = 0xFE
# 0xFF can never be an ID: it would be indistinguishable from a third header byte.
MAX_ID = 0xFE
# LEN counts params + CODE + CHK, so 250 params means LEN 252. (scservo_sdk is
# stricter: it sends at most 250 bytes in all, i.e. 244 params.)
MAX_PARAMS = 250
MIN_LEN = 2
MAX_LEN = MAX_PARAMS + 2


class Instruction(IntEnum):
    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04  # buffered in the servo until ACTION
    ACTION = 0x05
    SYNC_READ = 0x82  # every listed servo answers with its own status packet
    SYNC_WRITE = 0x83  # never answered


class ServoError(IntFlag):
    """The error byte of a status packet.

    Bits 4, 6 and 7 have no documented meaning on the STS series. IntFlag keeps
    unknown bits (boundary KEEP), so ``ServoError(raw)`` never raises and the
    raw value survives for logs.
    """

    VOLTAGE = 1
    ANGLE = 2  # angle / position sensor
    OVERHEAT = 4
    OVERCURRENT = 8
    OVERLOAD = 32


def checksum(body: bytes | bytearray | memoryview) -> int:
    """Checksum over ``body`` = ID, LEN, CODE and params (everything but header and CHK)."""
    return ~sum(body) & 0xFF


def _byte(what: str, value: int, lo: int = 0, hi: int = 0xFF) -> int:
    if not lo <= value <= hi:
        raise ValueError(f"{what} must be in {lo}..{hi}, got {value}")
    return value


@dataclass(frozen=True, slots=True)
class Packet:
    """One packet; ``code`` is the instruction (to a servo) or error byte (from one)."""

    id: int
    code: int
    params: bytes = b""

    def __post_init__(self) -> None:
        # Validated at construction so an unencodable Packet cannot exist.
        _byte("servo id", self.id, 0, MAX_ID)
        _byte("instruction/error code", self.code)
        if len(self.params) > MAX_PARAMS:
            raise ValueError(f"at most {MAX_PARAMS} parameter bytes, got {len(self.params)}")

    @property
    def error(self) -> ServoError:
        """``code`` read as a status packet's error flags."""
        return ServoError(self.code)

    def encode(self) -> bytes:
        body = bytes((self.id, len(self.params) + 2, self.code)) + bytes(self.params)
        return HEADER + body + bytes((checksum(body),))


def ping(id: int) -> bytes:
    return Packet(id, Instruction.PING).encode()


def read(id: int, address: int, length: int) -> bytes:
    # The reply carries `length` params, so it must itself fit in one packet.
    _byte("read length", length, 1, MAX_PARAMS)
    return Packet(id, Instruction.READ, bytes((_byte("address", address), length))).encode()


def _write(instruction: Instruction, id: int, address: int, data: bytes) -> bytes:
    if not data:
        raise ValueError("write needs at least one data byte")
    return Packet(id, instruction, bytes((_byte("address", address),)) + bytes(data)).encode()


def write(id: int, address: int, data: bytes) -> bytes:
    return _write(Instruction.WRITE, id, address, data)


def reg_write(id: int, address: int, data: bytes) -> bytes:
    """Like ``write`` but held by the servo until ``action`` (synchronised start)."""
    return _write(Instruction.REG_WRITE, id, address, data)


def action(id: int = BROADCAST_ID) -> bytes:
    return Packet(id, Instruction.ACTION).encode()


def _targets(ids: Sequence[int] | Mapping[int, bytes]) -> list[int]:
    out = list(ids)
    if not out:
        raise ValueError("a sync instruction needs at least one servo id")
    for sid in out:
        # The broadcast ID inside a sync packet would address every servo at once.
        _byte("servo id in a sync packet", sid, 0, BROADCAST_ID - 1)
    if len(set(out)) != len(out):
        raise ValueError(f"duplicate servo id in {out}")
    return out


def sync_read(address: int, length: int, ids: Sequence[int]) -> bytes:
    """One request; each listed servo answers, in order, with its own status packet."""
    _byte("read length", length, 1, MAX_PARAMS)
    params = bytes((_byte("address", address), length, *_targets(ids)))
    return Packet(BROADCAST_ID, Instruction.SYNC_READ, params).encode()


def sync_write(address: int, length: int, data_by_id: Mapping[int, bytes]) -> bytes:
    """The same register span written to many servos in one packet (no reply)."""
    _byte("write length", length, 1, MAX_PARAMS)
    params = bytearray((_byte("address", address), length))
    for sid in _targets(data_by_id):
        data = data_by_id[sid]
        # The servos slice the packet by `length`: one short entry would shift
        # every later servo onto the wrong bytes.
        if len(data) != length:
            raise ValueError(
                f"sync_write data for id {sid} is {len(data)} bytes, expected {length}"
            )
        params.append(sid)
        params += data
    return Packet(BROADCAST_ID, Instruction.SYNC_WRITE, bytes(params)).encode()


def status(id: int, error: int, params: bytes = b"") -> bytes:
    """A servo's reply; the simulated bus speaks with these."""
    return Packet(id, error, bytes(params)).encode()


def decode(buffer: bytes | bytearray | memoryview) -> tuple[int, Packet | None]:
    """Find the first valid packet in ``buffer``.

    Returns ``(consumed, packet)``: the caller deletes ``consumed`` bytes from
    the front of its buffer. With no complete packet, ``consumed`` counts only
    the garbage already ruled out, so a packet that is still arriving is kept
    and the call can be repeated after every chunk, even one byte at a time.

    A candidate header whose ID is 0xFF, whose LEN is impossible or whose
    checksum fails is rejected one byte at a time, so a real header hidden
    inside the rejected bytes is still found (resynchronisation).

    A corrupt but plausible LEN makes the candidate look incomplete until
    enough bytes arrive to check it; the caller's reply deadline bounds that.
    """
    data = bytes(buffer)
    n = len(data)
    start = 0
    while True:
        at = data.find(HEADER, start)
        if at < 0:
            # A trailing lone FF may be the first half of the next header.
            return (n - 1 if data.endswith(b"\xff") else n), None
        if n - at < 4:
            return at, None
        pid, length = data[at + 2], data[at + 3]
        # FF FF FF id ...: extra leading FFs (line idle / padding) slide the
        # window by one; the same step discards an impossible LEN.
        if pid > MAX_ID or not MIN_LEN <= length <= MAX_LEN:
            start = at + 1
            continue
        end = at + 4 + length
        if end > n:
            return at, None
        if checksum(data[at + 2 : end - 1]) != data[end - 1]:
            start = at + 1
            continue
        return end, Packet(pid, data[at + 4], data[at + 5 : end - 1])
