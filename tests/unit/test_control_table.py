"""The STS3215 control table and its sign-magnitude value codec."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given
from hypothesis import strategies as st

from lupin import control_table as ct
from lupin.control_table import REGISTERS, Register, decode_value, encode_value

R = REGISTERS


# --- sign-magnitude, checked against hand-computed words ----------------------


@pytest.mark.parametrize(
    ("name", "value", "raw"),
    [
        ("goal_position", 2048, 0x0800),
        ("goal_position", -1, 0x8001),  # not 0xFFFF: two's complement would be -32767
        ("goal_position", -2048, 0x8800),
        ("goal_speed", -1000, 0x83E8),
        ("present_speed", 32767, 0x7FFF),
        ("present_speed", -32767, 0xFFFF),
        ("homing_offset", -1, 0x0801),
        ("homing_offset", -2047, 0x0FFF),
        ("homing_offset", 2047, 0x07FF),
        ("present_load", -1000, 0x07E8),
        ("present_load", 1000, 0x03E8),
        ("present_load", -1, 0x0401),
        ("torque_limit", 1000, 0x03E8),
        ("model", 777, 0x0309),
    ],
)
def test_known_words(name: str, value: int, raw: int) -> None:
    reg = R[name]
    assert encode_value(reg, value) == raw.to_bytes(2, "little")
    assert decode_value(reg, raw.to_bytes(2, "little")) == value


def test_one_byte_registers() -> None:
    assert encode_value(R["torque_enable"], ct.TorqueEnable.RECENTRE) == b"\x80"
    assert encode_value(R["operating_mode"], ct.OperatingMode.VELOCITY) == b"\x01"
    assert decode_value(R["present_voltage"], b"\x78") == 120  # 12.0 V


def test_negative_zero_reads_zero() -> None:
    assert decode_value(R["goal_position"], b"\x00\x80") == 0
    assert decode_value(R["homing_offset"], b"\x00\x08") == 0
    assert encode_value(R["goal_position"], 0) == b"\x00\x00"


SIGNED = [r for r in REGISTERS.values() if r.sign_bit is not None]
UNSIGNED = [r for r in REGISTERS.values() if r.sign_bit is None]


@pytest.mark.parametrize("reg", SIGNED, ids=lambda r: r.name)
@given(data=st.data())
def test_signed_round_trip(reg: Register, data: st.DataObject) -> None:
    assert reg.sign_bit is not None
    top = (1 << reg.sign_bit) - 1
    value = data.draw(st.integers(-top, top))
    raw = encode_value(reg, value)
    assert len(raw) == reg.size
    assert decode_value(reg, raw) == value
    word = int.from_bytes(raw, "little")
    assert bool(word & (1 << reg.sign_bit)) == (value < 0)
    assert word & ((1 << reg.sign_bit) - 1) == abs(value)


@pytest.mark.parametrize("reg", UNSIGNED, ids=lambda r: r.name)
@given(data=st.data())
def test_unsigned_round_trip(reg: Register, data: st.DataObject) -> None:
    value = data.draw(st.integers(0, 256**reg.size - 1))
    assert decode_value(reg, encode_value(reg, value)) == value


@pytest.mark.parametrize(
    ("name", "value", "shown"),
    [
        ("goal_position", 32768, "-32767..32767"),
        ("goal_position", -32768, "-32767..32767"),
        ("homing_offset", 2048, "-2047..2047"),
        ("homing_offset", -2048, "-2047..2047"),
        ("present_load", 1024, "-1023..1023"),
        ("id", 256, "0..255"),
        ("id", -1, "0..255"),
        ("torque_limit", 65536, "0..65535"),
        ("goal_time", -1, "0..65535"),
    ],
)
def test_out_of_range_is_refused_never_wrapped(name: str, value: int, shown: str) -> None:
    with pytest.raises(ValueError, match=name) as err:
        encode_value(R[name], value)
    assert shown in str(err.value)


def test_non_integers_are_refused() -> None:
    with pytest.raises(TypeError):
        encode_value(R["goal_position"], 1.5)  # type: ignore[arg-type]


@pytest.mark.parametrize("data", [b"", b"\x00", b"\x00\x00\x00"])
def test_decode_refuses_wrong_length(data: bytes) -> None:
    with pytest.raises(ValueError, match="goal_position"):
        decode_value(R["goal_position"], data)


# --- decode_block ------------------------------------------------------------


def test_decode_block_state_read() -> None:
    block = (
        encode_value(R["present_position"], 3000)
        + encode_value(R["present_speed"], -150)
        + encode_value(R["present_load"], -300)
    )
    got = ct.decode_block(56, block, ["present_position", "present_speed", "present_load"])
    assert got == {"present_position": 3000, "present_speed": -150, "present_load": -300}


def test_decode_block_with_gaps_and_offset_start() -> None:
    # 62..70: voltage, temperature, (64 unlisted), status, moving, (67, 68), current
    block = bytes([121, 45, 0xEE, 0x20, 1, 0xEE, 0xEE]) + (300).to_bytes(2, "little")
    got = ct.decode_block(62, block, ["present_current", "moving", "present_voltage", "status"])
    assert got == {"present_current": 300, "moving": 1, "present_voltage": 121, "status": 0x20}


def test_decode_block_refuses_register_outside_block() -> None:
    with pytest.raises(ValueError, match=r"present_load .* not inside"):
        ct.decode_block(56, bytes(5), ["present_position", "present_load"])  # short reply
    with pytest.raises(ValueError, match=r"present_speed .* not inside"):
        ct.decode_block(56, bytes(2), ["present_speed"])
    with pytest.raises(ValueError, match="goal_position"):
        ct.decode_block(56, bytes(6), ["goal_position"])
    with pytest.raises(KeyError):
        ct.decode_block(56, bytes(6), ["no_such_register"])


# --- the table itself --------------------------------------------------------


def test_registers_do_not_overlap_and_names_match_keys() -> None:
    spans: list[tuple[int, int, str]] = sorted(
        (r.address, r.address + r.size, name) for name, r in REGISTERS.items()
    )
    for (_, end, a), (start, _, b) in itertools.pairwise(spans):
        assert end <= start, f"{a} overlaps {b}"
    assert all(r.name == name and r.size in (1, 2) for name, r in REGISTERS.items())


def test_eeprom_is_below_40_and_read_only_set() -> None:
    for r in REGISTERS.values():
        assert r.eeprom == (r.address < 40), r.name
    assert not R["lock"].eeprom  # the EEPROM lock is itself RAM
    assert {n for n, r in REGISTERS.items() if r.readonly} == {
        "firmware_major",
        "firmware_minor",
        "model",
        "present_position",
        "present_speed",
        "present_load",
        "present_voltage",
        "present_temperature",
        "status",
        "moving",
        "present_current",
    }


def test_spec_section_2_addresses() -> None:
    # SPEC.md §2, written independently of the table.
    spec = {
        "id": 5, "baud_rate": 6, "return_delay": 7, "min_position_limit": 9,
        "max_position_limit": 11, "p_coefficient": 21, "d_coefficient": 22,
        "i_coefficient": 23, "homing_offset": 31, "operating_mode": 33,
        "torque_enable": 40, "acceleration": 41, "goal_position": 42, "goal_speed": 46,
        "torque_limit": 48, "lock": 55, "present_position": 56, "present_speed": 58,
        "present_load": 60, "present_voltage": 62, "present_temperature": 63,
        "status": 65, "moving": 66, "present_current": 69,
    }  # fmt: skip
    assert {n: R[n].address for n in spec} == spec


def test_by_address() -> None:
    assert ct.by_address(42) is R["goal_position"]
    assert ct.by_address(31).sign_bit == 11
    with pytest.raises(KeyError):
        ct.by_address(43)  # the high byte of goal_position, not a register


def test_table_is_read_only() -> None:
    with pytest.raises(TypeError):
        REGISTERS["goal_position"] = R["goal_time"]  # type: ignore[index]
