"""The I/O-free Feetech codec: known bytes, stream decoding, resynchronisation."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable

import pytest
from hypothesis import given
from hypothesis import strategies as st

from lupin import protocol
from lupin.protocol import Instruction, Packet, ServoError, decode


def h(text: str) -> bytes:
    return bytes.fromhex(text)


def feed(chunks: Iterable[bytes]) -> tuple[list[Packet], bytes]:
    """The caller's loop: append each chunk, decode until nothing more, trim."""
    buf = bytearray()
    out: list[Packet] = []
    for chunk in chunks:
        buf += chunk
        while True:
            consumed, pkt = decode(buf)
            assert 0 <= consumed <= len(buf)
            del buf[:consumed]
            if pkt is None:
                break
            out.append(pkt)
    return out, bytes(buf)


def split_every(data: bytes, cuts: Iterable[int]) -> list[bytes]:
    points = sorted({c % (len(data) + 1) for c in cuts})
    edges = [0, *points, len(data)]
    return [data[a:b] for a, b in itertools.pairwise(edges)]


P1 = Packet(1, 0, b"\x00\x08")  # status: present position 2048
P2 = Packet(2, ServoError.OVERLOAD, b"")
P3 = Packet(3, 0x20 | 0x01, b"\x11\x22\x33")


# --- known bytes, computed by hand from CHK = ~(ID+LEN+CODE+ΣP) & 0xFF ---------


@pytest.mark.parametrize(
    ("built", "expected"),
    [
        (protocol.ping(1), "FF FF 01 02 01 FB"),
        (protocol.read(1, 56, 2), "FF FF 01 04 02 38 02 BE"),
        (protocol.write(1, 42, b"\x00\x08"), "FF FF 01 05 03 2A 00 08 C4"),
        (protocol.reg_write(1, 42, b"\x00\x08"), "FF FF 01 05 04 2A 00 08 C3"),
        (protocol.action(), "FF FF FE 02 05 FA"),
        (protocol.sync_read(56, 6, [1, 2]), "FF FF FE 06 82 38 06 01 02 38"),
        (
            protocol.sync_write(42, 2, {1: b"\x00\x08", 2: b"\xff\x0f"}),
            "FF FF FE 0A 83 2A 02 01 00 08 02 FF 0F 2F",
        ),
        (protocol.status(1, 0, b"\x00\x08"), "FF FF 01 04 00 00 08 F2"),
    ],
)
def test_builders_match_hand_computed_bytes(built: bytes, expected: str) -> None:
    assert built == h(expected)


def test_checksum_of_ping_body() -> None:
    assert protocol.checksum(b"\x01\x02\x01") == 0xFB
    # Wraps past 255: 0xFE + 0x0A + 0x83 + ... = 720 -> 0xD0 -> 0x2F.
    assert protocol.checksum(h("FE 0A 83 2A 02 01 00 08 02 FF 0F")) == 0x2F


def test_packet_validation() -> None:
    with pytest.raises(ValueError, match="servo id"):
        Packet(0xFF, Instruction.PING)
    with pytest.raises(ValueError, match="servo id"):
        Packet(-1, Instruction.PING)
    with pytest.raises(ValueError, match="250"):
        Packet(1, Instruction.WRITE, bytes(251))
    biggest = Packet(1, Instruction.WRITE, bytes(250)).encode()
    assert biggest[3] == 252
    assert decode(biggest) == (len(biggest), Packet(1, Instruction.WRITE, bytes(250)))


@pytest.mark.parametrize(
    "call",
    [
        lambda: protocol.read(1, 56, 0),
        lambda: protocol.read(1, 256, 2),
        lambda: protocol.write(1, 42, b""),
        lambda: protocol.sync_read(56, 2, []),
        lambda: protocol.sync_read(56, 2, [1, protocol.BROADCAST_ID]),
        lambda: protocol.sync_read(56, 2, [1, 1]),
        lambda: protocol.sync_write(42, 2, {}),
        lambda: protocol.sync_write(42, 2, {1: b"\x00\x08", 2: b"\x00"}),
        lambda: protocol.sync_write(42, 2, {1: b"\x00\x08\x00"}),
        lambda: protocol.sync_write(0, 1, {i: b"\x00" for i in range(125)}),
    ],
)
def test_builders_refuse_what_no_servo_could_parse(call: Callable[[], bytes]) -> None:
    with pytest.raises(ValueError):
        call()


def test_sync_write_names_the_offending_id() -> None:
    with pytest.raises(ValueError, match="id 7"):
        protocol.sync_write(42, 2, {1: b"\x00\x08", 7: b"\x00"})


def test_status_error_flags_keep_unknown_bits() -> None:
    (_, pkt) = decode(protocol.status(4, 0x20 | 0x04 | 0x40))
    assert pkt is not None
    assert ServoError.OVERLOAD in pkt.error
    assert ServoError.OVERHEAT in pkt.error
    assert ServoError.VOLTAGE not in pkt.error
    assert int(pkt.error) == 0x64  # bit 6 has no name but is not dropped


# --- decode ------------------------------------------------------------------


def test_decode_whole_packet() -> None:
    raw = P1.encode()
    assert decode(raw) == (len(raw), P1)
    assert decode(bytearray(raw)) == (len(raw), P1)
    assert decode(memoryview(raw)) == (len(raw), P1)


def test_decode_empty_and_pure_garbage() -> None:
    assert decode(b"") == (0, None)
    assert decode(b"\x00\x12\x34") == (3, None)
    # A trailing FF could start the next header: keep it.
    assert decode(b"\x00\x12\xff") == (2, None)


def test_decode_every_two_way_split() -> None:
    raw = P1.encode() + P3.encode()
    for cut in range(len(raw) + 1):
        assert feed([raw[:cut], raw[cut:]]) == ([P1, P3], b"")


def test_decode_byte_by_byte() -> None:
    raw = P1.encode() + P2.encode() + P3.encode()
    assert feed(raw[i : i + 1] for i in range(len(raw))) == ([P1, P2, P3], b"")


def test_garbage_before_and_between_packets() -> None:
    raw = b"\x00\x12\xfe" + P1.encode() + b"\xaa\xff\x00" + P2.encode() + b"\x55"
    assert feed([raw]) == ([P1, P2], b"")
    consumed, pkt = decode(raw)
    assert (consumed, pkt) == (3 + len(P1.encode()), P1)


def test_bad_checksum_is_dropped_and_next_packet_found() -> None:
    bad = bytearray(P1.encode())
    bad[-1] ^= 0x01
    assert feed([bytes(bad) + P2.encode()]) == ([P2], b"")


def test_header_hidden_inside_a_rejected_candidate_is_found() -> None:
    # FF FF 05 02 claims a 6-byte packet whose CODE and CHK are P2's header;
    # its checksum fails, and resync must find P2 starting inside it.
    raw = b"\xff\xff\x05\x02" + P2.encode()
    assert feed([raw]) == ([P2], b"")
    assert feed(raw[i : i + 1] for i in range(len(raw))) == ([P2], b"")


@pytest.mark.parametrize("bogus_len", [0x00, 0x01, 0xFD, 0xFF])
def test_bogus_len_resyncs(bogus_len: int) -> None:
    raw = bytes((0xFF, 0xFF, 0x01, bogus_len)) + P3.encode()
    assert feed([raw]) == ([P3], b"")
    assert feed(raw[i : i + 1] for i in range(len(raw))) == ([P3], b"")


@pytest.mark.parametrize("extra", [1, 2, 5])
def test_extra_leading_ffs(extra: int) -> None:
    raw = b"\xff" * extra + P1.encode()
    assert decode(raw) == (len(raw), P1)
    assert feed(raw[i : i + 1] for i in range(len(raw))) == ([P1], b"")


def test_id_ff_is_never_a_packet() -> None:
    # FF FF FF 02 01 CHK checksums correctly as if ID were 0xFF; no servo can
    # have that ID, so it is a spare FF in front of FF FF 02 01 .., not a packet.
    raw = b"\xff\xff\xff\x02\x01" + bytes([protocol.checksum(b"\xff\x02\x01")])
    assert decode(raw) == (len(raw), None)
    # A partial packet behind a spare FF: only the spare FF is consumed.
    assert decode(b"\xff" + P3.encode()[:5]) == (1, None)


def test_truncated_packet_is_kept_not_consumed() -> None:
    raw = P3.encode()
    for cut in range(len(raw)):
        assert decode(raw[:cut]) == (0, None)
        # Garbage in front is discarded, the partial packet is kept.
        assert decode(b"\x00\x01" + raw[:cut]) == (2, None)
    assert feed([b"\x07" + raw[:-1]]) == ([], raw[:-1])


def test_packet_cut_short_then_a_full_one() -> None:
    # The cut packet's LEN swallows the start of P1, fails its checksum, and
    # the decoder rescans from inside it.
    raw = protocol.read(1, 56, 2)[:5] + P1.encode()
    assert feed([raw]) == ([P1], b"")


# --- properties --------------------------------------------------------------

packets = st.builds(
    Packet,
    id=st.integers(0, protocol.BROADCAST_ID),
    code=st.integers(0, 0xFF),
    params=st.binary(max_size=protocol.MAX_PARAMS),
)
no_ff = st.binary(max_size=8).map(lambda b: b.replace(b"\xff", b""))
# Uniform random bytes rarely form a header; this alphabet is mostly headers,
# small LENs and IDs, so near-misses (and lucky checksums) turn up often.
noise = st.one_of(
    st.binary(max_size=600),
    st.lists(st.sampled_from(b"\xff\xff\xff\x00\x01\x02\x03\xfd\xfe"), max_size=64).map(bytes),
)


@given(packets)
def test_encode_then_decode_round_trips(pkt: Packet) -> None:
    raw = pkt.encode()
    assert raw[3] == len(pkt.params) + 2
    assert decode(raw) == (len(raw), pkt)


@given(st.lists(st.tuples(no_ff, packets), max_size=5), st.lists(st.integers(0, 2000)))
def test_stream_with_garbage_and_any_chunking(
    items: list[tuple[bytes, Packet]], cuts: list[int]
) -> None:
    raw = b"".join(g + p.encode() for g, p in items)
    assert feed(split_every(raw, cuts)) == ([p for _, p in items], b"")


@given(noise)
def test_arbitrary_bytes_never_raise(data: bytes) -> None:
    consumed, pkt = decode(data)
    assert 0 <= consumed <= len(data)
    if pkt is not None:
        # Whatever is returned is exactly the bytes just before `consumed`.
        raw = pkt.encode()
        assert data[consumed - len(raw) : consumed] == raw


@given(noise, st.lists(st.integers(0, 600)))
def test_chunking_never_changes_the_result(data: bytes, cuts: list[int]) -> None:
    assert feed(split_every(data, cuts)) == feed([data])
