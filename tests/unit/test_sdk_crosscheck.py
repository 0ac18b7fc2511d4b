"""lupin.protocol and lupin.control_table against the vendor SDK, byte for byte.

The SDK (``scservo_sdk``, PyPI ``feetech-servo-sdk``) is driven against a fake
port that records what it writes and serves canned replies, which are built
with ``protocol.status`` so the SDK's parser also vouches for our replies.
"""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from lupin import protocol
from lupin.control_table import REGISTERS, decode_value, encode_value

scs: Any = pytest.importorskip("scservo_sdk")


class FakePort:
    """Just the PortHandler surface the SDK's packet handler touches."""

    def __init__(self, *replies: bytes) -> None:
        self.is_using = False
        self.writes: list[bytes] = []
        self.rx = bytearray(b"".join(replies))

    def clearPort(self) -> None:
        pass

    def writePort(self, packet: list[int]) -> int:
        self.writes.append(bytes(packet))
        return len(packet)

    def readPort(self, length: int) -> bytes:
        chunk = bytes(self.rx[:length])
        del self.rx[:length]
        return chunk

    def setPacketTimeout(self, packet_length: int) -> None:
        pass

    def setPacketTimeoutMillis(self, msec: float) -> None:
        pass

    def isPacketTimeout(self) -> bool:
        # Nothing more will ever arrive, so the SDK's busy-wait ends at once.
        return not self.rx


@pytest.fixture
def ph() -> Any:
    # PacketHandler(0) sets the SDK's *global* byte order to little-endian.
    return scs.PacketHandler(0)


ids = st.integers(0, protocol.BROADCAST_ID - 1)
addresses = st.integers(0, 0xFF)


def test_constants_agree_with_sdk() -> None:
    assert protocol.BROADCAST_ID == scs.BROADCAST_ID
    for inst, sdk in [
        (protocol.Instruction.PING, scs.INST_PING),
        (protocol.Instruction.READ, scs.INST_READ),
        (protocol.Instruction.WRITE, scs.INST_WRITE),
        (protocol.Instruction.REG_WRITE, scs.INST_REG_WRITE),
        (protocol.Instruction.ACTION, scs.INST_ACTION),
        (protocol.Instruction.SYNC_READ, scs.INST_SYNC_READ),
        (protocol.Instruction.SYNC_WRITE, scs.INST_SYNC_WRITE),
    ]:
        assert inst == sdk, inst.name
    err = protocol.ServoError
    assert err.VOLTAGE == scs.ERRBIT_VOLTAGE
    assert err.ANGLE == scs.ERRBIT_ANGLE
    assert err.OVERHEAT == scs.ERRBIT_OVERHEAT
    assert err.OVERCURRENT == scs.ERRBIT_OVERELE
    assert err.OVERLOAD == scs.ERRBIT_OVERLOAD


def test_ping_then_model_read(ph: Any) -> None:
    # The SDK's ping is two transactions: PING, then READ of the model (address 3).
    port = FakePort(protocol.status(1, 0), protocol.status(1, 0, b"\x09\x03"))
    model, result, error = ph.ping(port, 1)
    assert (model, result, error) == (777, scs.COMM_SUCCESS, 0)
    assert port.writes == [protocol.ping(1), protocol.read(1, 3, 2)]


def test_read_with_reply(ph: Any) -> None:
    port = FakePort(protocol.status(1, 0x20, b"\x00\x88"))
    value, result, error = ph.read2ByteTxRx(port, 1, 56)
    assert (result, error) == (scs.COMM_SUCCESS, 0x20)
    assert port.writes == [protocol.read(1, 56, 2)]
    assert scs.SCS_TOHOST(value, 15) == decode_value(REGISTERS["present_position"], b"\x00\x88")


@given(ids, addresses, st.integers(1, protocol.MAX_PARAMS))
def test_read_tx(sid: int, address: int, length: int) -> None:
    port = FakePort()
    assert scs.PacketHandler(0).readTx(port, sid, address, length) == scs.COMM_SUCCESS
    assert port.writes == [protocol.read(sid, address, length)]


@given(ids, addresses, st.integers(0, 0xFF), st.integers(0, 0xFFFF))
def test_write_1_and_2_byte(sid: int, address: int, b: int, w: int) -> None:
    ph = scs.PacketHandler(0)
    port = FakePort()
    ph.write1ByteTxOnly(port, sid, address, b)
    ph.write2ByteTxOnly(port, sid, address, w)
    assert port.writes == [
        protocol.write(sid, address, bytes([b])),
        protocol.write(sid, address, w.to_bytes(2, "little")),
    ]


# The SDK refuses a packet over 250 bytes in all, i.e. more than 244 params.
@given(ids, addresses, st.binary(min_size=1, max_size=243))
def test_write_and_reg_write_n_bytes(sid: int, address: int, data: bytes) -> None:
    ph = scs.PacketHandler(0)
    port = FakePort()
    assert ph.writeTxOnly(port, sid, address, len(data), list(data)) == scs.COMM_SUCCESS
    assert ph.regWriteTxOnly(port, sid, address, len(data), list(data)) == scs.COMM_SUCCESS
    assert port.writes == [
        protocol.write(sid, address, data),
        protocol.reg_write(sid, address, data),
    ]


def test_write_with_reply_reports_the_error_byte(ph: Any) -> None:
    port = FakePort(protocol.status(3, protocol.ServoError.OVERHEAT))
    result, error = ph.write1ByteTxRx(port, 3, 40, 1)
    assert (result, error) == (scs.COMM_SUCCESS, protocol.ServoError.OVERHEAT)
    assert port.writes == [protocol.write(3, 40, b"\x01")]


def test_action(ph: Any) -> None:
    port = FakePort(protocol.status(5, 0))
    assert ph.action(port, scs.BROADCAST_ID) == scs.COMM_SUCCESS  # broadcast: no reply awaited
    assert ph.action(port, 5) == scs.COMM_SUCCESS
    assert port.writes == [protocol.action(), protocol.action(5)]


@given(
    addresses,
    st.integers(1, 8),
    st.lists(ids, min_size=1, max_size=20, unique=True),
    st.data(),
)
def test_group_sync_write(address: int, length: int, sids: list[int], data: st.DataObject) -> None:
    payload = {sid: data.draw(st.binary(min_size=length, max_size=length)) for sid in sids}
    port = FakePort()
    group = scs.GroupSyncWrite(port, scs.PacketHandler(0), address, length)
    for sid, d in payload.items():
        assert group.addParam(sid, list(d))
    assert group.txPacket() == scs.COMM_SUCCESS
    assert port.writes == [protocol.sync_write(address, length, payload)]


def test_group_sync_read_tx_and_replies(ph: Any) -> None:
    pos, speed, load = (REGISTERS[n] for n in ("present_position", "present_speed", "present_load"))
    block = {
        1: encode_value(pos, 2048) + encode_value(speed, -40) + encode_value(load, -200),
        2: encode_value(pos, 100) + encode_value(speed, 7) + encode_value(load, 1000),
    }
    port = FakePort(*(protocol.status(sid, 0, b) for sid, b in block.items()))
    group = scs.GroupSyncRead(port, ph, 56, 6)
    for sid in block:
        assert group.addParam(sid)
    assert group.txRxPacket() == scs.COMM_SUCCESS
    assert port.writes == [protocol.sync_read(56, 6, [1, 2])]
    for sid, raw in block.items():
        assert group.getData(sid, 56, 2) == int.from_bytes(raw[0:2], "little")
        assert scs.SCS_TOHOST(group.getData(sid, 58, 2), 15) == decode_value(speed, raw[2:4])
        assert scs.SCS_TOHOST(group.getData(sid, 60, 2), 10) == decode_value(load, raw[4:6])


@given(st.lists(ids, min_size=1, max_size=40, unique=True), addresses, st.integers(1, 250))
def test_sync_read_tx(sids: list[int], address: int, length: int) -> None:
    port = FakePort()
    ph = scs.PacketHandler(0)
    assert ph.syncReadTx(port, address, length, sids, len(sids)) == scs.COMM_SUCCESS
    assert port.writes == [protocol.sync_read(address, length, sids)]


# --- sign-magnitude against SCS_TOSCS / SCS_TOHOST, exhaustively ---------------


@pytest.mark.parametrize("name", ["goal_position", "homing_offset", "present_load"])
def test_sign_encoding_matches_sdk(name: str) -> None:
    reg = REGISTERS[name]
    assert reg.sign_bit is not None
    lo, hi = reg.value_range
    for value in range(lo, hi + 1):
        assert encode_value(reg, value) == scs.SCS_TOSCS(value, reg.sign_bit).to_bytes(
            2, "little"
        ), value
    # Every 16-bit word reads the same, even ones with junk above the sign bit.
    for raw in range(0x10000):
        assert decode_value(reg, raw.to_bytes(2, "little")) == scs.SCS_TOHOST(raw, reg.sign_bit)


def test_signed_goal_through_the_sdk_write(ph: Any) -> None:
    port = FakePort()
    goal = REGISTERS["goal_position"]
    ph.write2ByteTxOnly(port, 1, goal.address, scs.SCS_TOSCS(-300, 15))
    assert port.writes == [protocol.write(1, goal.address, encode_value(goal, -300))]
