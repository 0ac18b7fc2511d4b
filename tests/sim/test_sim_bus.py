"""SimulatedBus: every instruction, the traffic log, and each injected fault."""

from __future__ import annotations

import pytest

from lupin import control_table as ct
from lupin import protocol as pr
from lupin.protocol import BROADCAST_ID, Instruction, Packet, ServoError
from lupin_adapters.sim.bus import SimServoSpec, SimulatedBus, build_sim_bus
from lupin_adapters.sim.faults import Reply

REG = ct.REGISTERS
GOAL = REG["goal_position"]
POS = REG["present_position"]


def pkt(raw: bytes) -> Packet:
    used, packet = pr.decode(raw)
    assert packet is not None and used == len(raw)
    return packet


def make_bus(*ids: int, seed: int = 0) -> SimulatedBus:
    return build_sim_bus([SimServoSpec(i, position=1000 + i) for i in ids], seed=seed)


def word(value: int) -> bytes:
    return ct.encode_value(GOAL, value)


def test_ping() -> None:
    bus = make_bus(1, 2)
    assert bus.handle(pkt(pr.ping(2)), 0.0) == [pr.status(2, 0)]
    assert bus.handle(pkt(pr.ping(5)), 0.0) == []  # nobody there


def test_read() -> None:
    bus = make_bus(1)
    assert bus.handle(pkt(pr.read(1, POS.address, 2)), 0.0) == [pr.status(1, 0, word(1001))]
    assert bus.handle(pkt(pr.read(1, 3, 2)), 0.0) == [pr.status(1, 0, (777).to_bytes(2, "little"))]


def test_write_applies_and_acks() -> None:
    bus = make_bus(1)
    assert bus.handle(pkt(pr.write(1, GOAL.address, word(1500))), 0.0) == [pr.status(1, 0)]
    assert bus[1].get("goal_position") == 1500


def test_broadcast_write_reaches_all_and_is_not_answered() -> None:
    bus = make_bus(1, 2, 3)
    assert bus.handle(pkt(pr.write(BROADCAST_ID, 40, b"\x01")), 0.0) == []
    assert all(s.torque for s in bus.servos)


def test_reg_write_waits_for_action() -> None:
    bus = make_bus(1, 2)
    for i in (1, 2):
        assert bus.handle(pkt(pr.reg_write(i, GOAL.address, word(3000))), 0.0) == [pr.status(i, 0)]
    assert bus[1].get("goal_position") == 1001
    assert bus.handle(pkt(pr.action()), 0.0) == []  # broadcast ACTION: no reply
    assert bus[1].get("goal_position") == bus[2].get("goal_position") == 3000


def test_sync_write_is_never_answered() -> None:
    bus = make_bus(1, 2, 3)
    raw = pr.sync_write(GOAL.address, 2, {1: word(100), 3: word(300)})
    assert bus.handle(pkt(raw), 0.0) == []
    assert [s.get("goal_position") for s in bus.servos] == [100, 1002, 300]


def test_sync_read_answers_in_listed_order() -> None:
    bus = make_bus(1, 2, 3)
    replies = bus.handle(pkt(pr.sync_read(POS.address, 2, [3, 1, 2])), 0.0)
    assert replies == [pr.status(i, 0, word(1000 + i)) for i in (3, 1, 2)]


def test_sync_read_with_a_dead_servo_in_the_middle() -> None:
    bus = make_bus(1, 2, 3)
    bus.kill(2)
    replies = bus.handle(pkt(pr.sync_read(POS.address, 2, [1, 2, 3])), 0.0)
    assert replies == [pr.status(i, 0, word(1000 + i)) for i in (1, 3)]
    bus.revive(2)
    assert len(bus.handle(pkt(pr.sync_read(POS.address, 2, [1, 2, 3])), 0.0)) == 3


def test_a_dead_servo_neither_answers_nor_acts() -> None:
    bus = make_bus(1)
    bus.kill(1)
    assert bus.handle(pkt(pr.write(1, 40, b"\x01")), 0.0) == []
    assert bus.handle(pkt(pr.ping(1)), 0.0) == []
    assert not bus[1].torque


def test_status_return_level_zero_answers_only_ping_and_read() -> None:
    bus = make_bus(1)
    bus[1].set("status_return_level", 0)
    assert bus.handle(pkt(pr.write(1, 40, b"\x01")), 0.0) == []
    assert bus[1].torque
    assert len(bus.handle(pkt(pr.read(1, 40, 1)), 0.0)) == 1
    assert len(bus.handle(pkt(pr.ping(1)), 0.0)) == 1


def test_malformed_and_unknown_instructions_go_unanswered() -> None:
    bus = make_bus(1)
    assert bus.handle(Packet(1, Instruction.READ, b"\x38"), 0.0) == []
    assert bus.handle(Packet(1, 0x42, b""), 0.0) == []


def test_error_bits_ride_on_every_status_packet() -> None:
    bus = make_bus(1)
    bus.set_error(1, ServoError.VOLTAGE)
    assert bus.handle(pkt(pr.ping(1)), 0.0) == [pr.status(1, ServoError.VOLTAGE)]


def test_changing_the_id_register_readdresses_the_servo() -> None:
    bus = make_bus(1)
    bus.handle(pkt(pr.write(1, REG["lock"].address, b"\x00")), 0.0)
    bus.handle(pkt(pr.write(1, REG["id"].address, b"\x05")), 0.0)
    assert bus.handle(pkt(pr.ping(1)), 0.0) == []
    assert bus.handle(pkt(pr.ping(5)), 0.0) == [pr.status(5, 0)]
    assert bus.ids == [5]


def test_physics_advances_to_each_packets_time() -> None:
    bus = make_bus(1)
    bus.handle(pkt(pr.write(1, GOAL.address, word(2001))), 0.0)
    bus.handle(pkt(pr.write(1, 40, b"\x01")), 0.0)
    bus.handle(pkt(pr.ping(1)), 0.2)  # 0.2 s at 3000 counts/s
    assert bus[1].present_position == pytest.approx(1601, abs=3)
    bus.advance(1.0)
    assert bus[1].present_position == 2001
    bus.advance(0.5)  # time never runs backwards
    assert bus[1].present_position == 2001


def test_log_and_write_helpers() -> None:
    bus = make_bus(1, 2)
    bus.handle(pkt(pr.ping(1)), 1.0)
    bus.handle(pkt(pr.write(1, 40, b"\x01")), 2.0)
    bus.handle(pkt(pr.sync_write(GOAL.address, 2, {1: word(10), 2: word(20)})), 3.0)
    bus.handle(pkt(pr.write(2, 41, bytes([5, *word(30)]))), 4.0)
    assert [t for t, _ in bus.received] == [1.0, 2.0, 3.0, 4.0]
    assert [(t, p.code) for t, p in bus.instructions(Instruction.PING)] == [(1.0, 1)]
    goals = bus.writes_to(GOAL.address)
    assert [(w.t, w.id, w.value("goal_position")) for w in goals] == [
        (3.0, 1, 10),
        (3.0, 2, 20),
        (4.0, 2, 30),  # a write starting at 41 covers 42 too
    ]
    assert [w.id for w in bus.writes_to(GOAL.address, since=3.5)] == [2]
    assert [w.t for w in bus.writes_to(GOAL.address, id=1)] == [3.0]
    assert goals[0].value("torque_enable") is None
    assert bus.writes_to(40)[0].instruction == Instruction.WRITE
    bus.clear_log()
    assert not bus.received and bus.writes() == []


def test_drop_fault_with_a_count() -> None:
    bus = make_bus(1, 2)
    bus.inject("drop", ids=[1], count=1)
    assert bus.handle(pkt(pr.ping(1)), 0.0) == []
    assert bus.handle(pkt(pr.ping(2)), 0.0) == [pr.status(2, 0)]  # other ids untouched
    assert bus.handle(pkt(pr.ping(1)), 0.0) == [pr.status(1, 0)]  # count used up
    assert bus.faults == []


def test_a_dropped_reply_still_means_the_write_was_applied() -> None:
    bus = make_bus(1)
    bus.inject("drop")
    assert bus.handle(pkt(pr.write(1, 40, b"\x01")), 0.0) == []
    assert bus[1].torque


def test_corrupt_fault_breaks_the_checksum() -> None:
    bus = make_bus(1)
    bus.inject("corrupt")
    for _ in range(20):
        (raw,) = bus.handle(pkt(pr.read(1, POS.address, 2)), 0.0)
        good = pr.status(1, 0, word(1001))
        assert len(raw) == len(good) and raw[:4] == good[:4] and raw != good
        assert pr.decode(raw)[1] is None


def test_truncate_fault_cuts_the_reply_short() -> None:
    bus = make_bus(1)
    bus.inject("truncate")
    good = pr.status(1, 0, word(1001))
    for _ in range(20):
        (raw,) = bus.handle(pkt(pr.read(1, POS.address, 2)), 0.0)
        assert 1 <= len(raw) < len(good) and good.startswith(raw)


def test_garbage_fault_precedes_a_good_reply() -> None:
    bus = make_bus(1)
    bus.inject("garbage")
    for _ in range(20):
        (raw,) = bus.handle(pkt(pr.ping(1)), 0.0)
        assert raw.endswith(pr.status(1, 0)) and len(raw) > 6 and 0xFF not in raw[:-6]
        assert pr.decode(raw) == (len(raw), Packet(1, 0))


def test_delay_fault_is_reported_to_timed_transports() -> None:
    bus = make_bus(1, 2)
    bus.inject("delay", ids=[2], seconds=0.25)
    replies = bus.respond(pkt(pr.sync_read(POS.address, 2, [1, 2])), 0.0)
    assert replies == [
        Reply(1, pr.status(1, 0, word(1001)), 0.0),
        Reply(2, pr.status(2, 0, word(1002)), 0.25),
    ]


def test_fault_rate_is_random_but_seeded() -> None:
    def run(seed: int) -> list[int]:
        bus = make_bus(1, seed=seed)
        bus.inject("drop", rate=0.5)
        return [len(bus.handle(pkt(pr.ping(1)), 0.0)) for _ in range(200)]

    first = run(7)
    assert first == run(7)
    assert 60 < sum(first) < 140
    bus = make_bus(1)
    bus.inject("drop", rate=0.0)
    assert all(bus.handle(pkt(pr.ping(1)), 0.0) for _ in range(50))
    bus.clear_faults()
    assert bus.faults == []


def test_inject_validates() -> None:
    bus = make_bus(1)
    with pytest.raises(ValueError, match="unknown fault kind"):
        bus.inject("gremlins")
    with pytest.raises(ValueError, match="seconds"):
        bus.inject("delay")
    with pytest.raises(ValueError, match="rate"):
        bus.inject("drop", rate=2.0)


def test_build_sim_bus_from_specs() -> None:
    bus = build_sim_bus(
        [
            SimServoSpec(1, position=1500, gravity=120.0, min_limit=1000, max_limit=3000),
            SimServoSpec(7, mode=1, p_gain=16, rest=100),
        ]
    )
    assert bus.ids == [1, 7]
    assert bus[1].present_position == 1500 and bus[1].physics.gravity == 120.0
    assert bus[1].get("min_position_limit") == 1000
    assert bus[7].get("operating_mode") == 1 and bus[7].get("p_coefficient") == 16
    assert bus[7].physics.rest == 100
    with pytest.raises(KeyError):
        bus.servo(3)


def test_sync_clock_skips_the_gap() -> None:
    bus = make_bus(1)
    bus.handle(pkt(pr.write(1, GOAL.address, word(3001))), 0.0)
    bus.handle(pkt(pr.write(1, 40, b"\x01")), 0.0)
    bus.sync_clock(5000.0)  # e.g. the pty server's monotonic clock takes over
    bus.advance(5000.1)
    assert bus[1].present_position == pytest.approx(1301, abs=3)
