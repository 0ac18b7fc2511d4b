"""ServoBus over the in-process null modem, the simulated servos at its far end.

Fast and deterministic: no pty, no serial driver, but the same bytes. The
manipulator hook splits, corrupts and drops replies on their way back, so
framing and recovery are tested without timing luck; the pty path has its own
tests (test_bus_pty.py).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import time
from collections.abc import AsyncIterator, Callable, Sequence

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lupin import control_table as ct
from lupin import protocol as pr
from lupin.bus import PRIORITY_CONTROL, PRIORITY_SERVICE, BusClosed, ServoBus
from lupin.protocol import Packet
from lupin_adapters.null_modem import Manipulator, NullModemLink, Responder
from lupin_adapters.sim.bus import SimServoSpec, SimulatedBus, build_sim_bus

REG = ct.REGISTERS
POS = REG["present_position"]
GOAL = REG["goal_position"]
MODEL = REG["model"]
IDS = (1, 2, 3)


def make_sim(*ids: int) -> SimulatedBus:
    return build_sim_bus([SimServoSpec(i, position=1000 + i) for i in ids])


def word(value: int) -> bytes:
    return ct.encode_value(GOAL, value)


def value(data: bytes | None) -> int | None:
    return None if data is None else ct.decode_value(POS, data)


def answered_by(sim: SimulatedBus) -> Responder:
    return lambda pkt, now: sim.handle(pkt, now)


@contextlib.asynccontextmanager
async def bus_on(
    sim: SimulatedBus | None = None,
    *,
    responder: Responder | None = None,
    manipulator: Manipulator | None = None,
    reply_margin_s: float = 0.05,  # generous: a busy CI machine must not fake a timeout
    retries: int = 1,
) -> AsyncIterator[tuple[ServoBus, NullModemLink]]:
    if responder is None:
        assert sim is not None
        responder = answered_by(sim)
    link = NullModemLink(responder, manipulator=manipulator)
    bus = ServoBus(link, reply_margin_s=reply_margin_s, retries=retries)
    try:
        yield bus, link
    finally:
        await bus.close()


# -- the happy path --------------------------------------------------------------


async def test_every_request_kind_reads_and_writes_the_servos() -> None:
    sim = make_sim(*IDS)
    async with bus_on(sim) as (bus, link):
        assert await bus.ping(2)
        assert value(await bus.read(1, POS.address, 2)) == 1001
        assert await bus.read(3, MODEL.address, 2) == (777).to_bytes(2, "little")
        assert await bus.write(1, GOAL.address, word(1500))
        assert sim[1].get("goal_position") == 1500

        result = await bus.sync_read(IDS, POS.address, 2)
        assert {i: value(d) for i, d in result.data.items()} == {1: 1001, 2: 1002, 3: 1003}
        assert result.missing == [] and result.errors == {}

        await bus.sync_write(GOAL.address, 2, {1: word(1100), 2: word(1200), 3: word(1300)})
        assert [sim[i].get("goal_position") for i in IDS] == [1100, 1200, 1300]

        # What went on the wire is the codec's packets, one per request, nothing else.
        assert link.sent == [
            pr.ping(2),
            pr.read(1, POS.address, 2),
            pr.read(3, MODEL.address, 2),
            pr.write(1, GOAL.address, word(1500)),
            pr.sync_read(POS.address, 2, IDS),
            pr.sync_write(GOAL.address, 2, {1: word(1100), 2: word(1200), 3: word(1300)}),
        ]
        assert not bus.stats.failures
        assert bus.stats.bytes_out == sum(map(len, link.sent))
        # 4 single status packets (6 bytes + params) and 3 of 8 bytes for the sync read.
        assert bus.stats.bytes_in == 6 + 8 + 8 + 6 + 3 * 8


async def test_a_missing_servo_is_false_or_none_not_an_exception() -> None:
    async with bus_on(make_sim(1), retries=0) as (bus, _link):
        assert not await bus.ping(9)
        assert await bus.read(9, POS.address, 2) is None
        assert not await bus.write(9, GOAL.address, word(100))
        assert bus.stats.failures["timeout"] == 3


async def test_servo_error_bits_come_back_with_the_data() -> None:
    sim = make_sim(*IDS)
    sim.set_error(2, int(pr.ServoError.OVERLOAD | pr.ServoError.OVERHEAT))
    async with bus_on(sim) as (bus, _link):
        result = await bus.sync_read(IDS, POS.address, 2)
    assert sorted(result.data) == [1, 2, 3]
    assert result.errors == {2: 36}
    assert bus.stats.failures["servo_error"] == 1


# -- a SYNC_READ keeps the servos that answered ------------------------------------


async def test_sync_read_with_a_dead_servo_returns_the_others() -> None:
    sim = make_sim(*IDS)
    sim.kill(2)
    async with bus_on(sim) as (bus, _link):
        result = await bus.sync_read(IDS, POS.address, 2)
        assert {i: value(d) for i, d in result.data.items()} == {1: 1001, 3: 1003}
        assert result.missing == [2]
        assert bus.stats.failures["timeout"] == 1
        sim.revive(2)
        assert (await bus.sync_read(IDS, POS.address, 2)).missing == []


@pytest.mark.parametrize("victim", [2, 3], ids=["middle", "last"])
@pytest.mark.parametrize("kind", ["drop", "corrupt", "truncate"])
async def test_sync_read_with_one_bad_reply_returns_the_others(kind: str, victim: int) -> None:
    sim = make_sim(*IDS)
    sim.inject(kind, ids=[victim], count=1)
    async with bus_on(sim) as (bus, _link):
        result = await bus.sync_read(IDS, POS.address, 2)
        others = {i: 1000 + i for i in IDS if i != victim}
        assert {i: value(d) for i, d in result.data.items()} == others
        assert result.missing == [victim]
        failures = bus.stats.failures
        # Exactly one servo is reported as not having answered...
        assert failures["timeout"] + failures["truncated"] == 1
        if kind == "drop":
            assert failures == {"timeout": 1}
        elif kind == "truncate" and victim == 3:
            assert failures["truncated"] == 1  # the cut packet was still waiting for its tail
        else:
            # ...and the bytes of a corrupt or cut reply are counted as garbled.
            assert failures["garbled"] > 0
        # The fault was a one-off: the next read is whole again.
        assert (await bus.sync_read(IDS, POS.address, 2)).missing == []


async def test_garbage_before_a_reply_is_skipped_and_counted() -> None:
    sim = make_sim(*IDS)

    def noisy(reply: bytes) -> Sequence[bytes]:
        return [b"\x00\x13\x37" + reply] if reply[2] == 2 else [reply]

    async with bus_on(sim, manipulator=noisy) as (bus, _link):
        result = await bus.sync_read(IDS, POS.address, 2)
    assert {i: value(d) for i, d in result.data.items()} == {1: 1001, 2: 1002, 3: 1003}
    assert bus.stats.failures == {"garbled": 3}


async def test_garbage_injected_by_the_sim_costs_no_data() -> None:
    sim = make_sim(*IDS)
    fault = sim.inject("garbage", count=3)
    async with bus_on(sim) as (bus, _link):
        result = await bus.sync_read(IDS, POS.address, 2)
    assert fault.fired == 3 and result.missing == []
    assert 3 <= bus.stats.failures["garbled"] <= 24  # 1..8 noise bytes before each reply


async def test_foreign_and_wrong_length_packets_are_refused_and_counted() -> None:
    sim = make_sim(*IDS)

    def confused(pkt: Packet, now: float) -> list[bytes]:
        # A servo nobody asked (id 7) and a reply of the wrong size, before the real ones.
        return [pr.status(7, 0, word(1)), pr.status(1, 0, b"\x01\x02\x03"), *sim.handle(pkt, now)]

    async with bus_on(responder=confused) as (bus, _link):
        result = await bus.sync_read(IDS, POS.address, 2)
    assert {i: value(d) for i, d in result.data.items()} == {1: 1001, 2: 1002, 3: 1003}
    assert bus.stats.failures["unexpected_id"] == 1
    assert bus.stats.failures["wrong_length"] == 1


# -- framing: however the line chunks it --------------------------------------------


def halves(reply: bytes) -> list[bytes]:
    return [reply[: len(reply) // 2], reply[len(reply) // 2 :]]


def bytewise(reply: bytes) -> list[bytes]:
    return [bytes((b,)) for b in reply]


@pytest.mark.parametrize("split", [halves, bytewise], ids=["halves", "byte-by-byte"])
async def test_split_replies_still_decode(split: Callable[[bytes], list[bytes]]) -> None:
    sim = make_sim(*IDS)
    async with bus_on(sim, manipulator=split) as (bus, _link):
        result = await bus.sync_read(IDS, POS.address, 2)
        assert {i: value(d) for i, d in result.data.items()} == {1: 1001, 2: 1002, 3: 1003}
        assert value(await bus.read(2, POS.address, 2)) == 1002
        assert await bus.ping(3)
        assert not bus.stats.failures


async def test_byte_by_byte_with_noise_between_packets() -> None:
    sim = make_sim(*IDS)

    def trickle(reply: bytes) -> list[bytes]:
        return bytewise(b"\x00\xfe" + reply)  # a lone FF-less pair before every reply

    async with bus_on(sim, manipulator=trickle) as (bus, _link):
        result = await bus.sync_read(IDS, POS.address, 2)
    assert sorted(result.data) == [1, 2, 3]
    assert bus.stats.failures == {"garbled": 6}


# -- late replies -----------------------------------------------------------------------


async def test_a_late_reply_is_counted_and_not_taken_for_the_next_answer() -> None:
    sim = make_sim(1)
    async with bus_on(sim, retries=0) as (bus, link):
        link.latency_s = 0.3  # far past the deadline: wire time + 50 ms
        assert await bus.read(1, POS.address, 2) is None
        assert bus.stats.failures["timeout"] == 1
        link.latency_s = 0.0
        # Same length, another register: the late position must not pass for the model.
        assert await bus.read(1, MODEL.address, 2) == (777).to_bytes(2, "little")
        await asyncio.sleep(0.3)  # the late reply lands between two exchanges
        assert value(await bus.read(1, GOAL.address, 2)) == 1001
        assert bus.stats.failures["stray_bytes"] == 8  # one 8-byte status, dropped


async def test_when_a_late_reply_and_the_fresh_one_arrive_together_the_fresh_wins() -> None:
    sim = make_sim(1)
    held: list[bytes] = []

    def late_once(pkt: Packet, now: float) -> list[bytes]:
        replies = sim.handle(pkt, now)
        if len(sim.received) == 1:
            held.extend(replies)  # the first answer is late...
            return []
        out = [b"".join(held + replies)]  # ...and lands just before the second one
        held.clear()
        return out

    async with bus_on(responder=late_once, retries=0) as (bus, _link):
        assert await bus.read(1, POS.address, 2) is None
        assert await bus.read(1, MODEL.address, 2) == (777).to_bytes(2, "little")
        assert bus.stats.failures["duplicate"] == 1
        # The bus stays in step afterwards.
        assert value(await bus.read(1, POS.address, 2)) == 1001
        assert await bus.read(1, MODEL.address, 2) == (777).to_bytes(2, "little")


class FifoLine:
    """A slow line that never reorders: each reply arrives ``lag`` after its request,
    and no sooner than ``gap`` after the one before (a USB adapter's latency timer)."""

    baud = 1_000_000

    def __init__(self, sim: SimulatedBus, lags: Sequence[float], lag: float, gap: float) -> None:
        self.sim, self.lags, self.lag, self.gap = sim, list(lags), lag, gap
        self.receive: Callable[[bytes], None] = lambda _data: None
        self.last_due = 0.0

    def set_receiver(self, callback: Callable[[bytes], None]) -> None:
        self.receive = callback

    def write(self, data: bytes) -> None:
        loop = asyncio.get_running_loop()
        _, pkt = pr.decode(data)
        assert pkt is not None
        lag = self.lags.pop(0) if self.lags else self.lag
        for reply in self.sim.handle(pkt, loop.time()):
            self.last_due = max(loop.time() + lag, self.last_due + self.gap)
            loop.call_at(self.last_due, self.receive, reply)

    async def close(self) -> None:
        pass


async def test_a_late_reply_ahead_of_the_fresh_one_does_not_put_the_bus_behind() -> None:
    """The first answer comes 50 ms late (past the deadline), the next right behind it.

    Taking the late answer for the second question would answer every later
    question with the previous one's reply, for good: the second exchange must
    listen to its deadline and let the fresh reply win.
    """
    sim = make_sim(1)
    line = FifoLine(sim, lags=[0.05], lag=0.01, gap=0.002)
    bus = ServoBus(line, reply_margin_s=0.03, retries=0)
    model, pos = (777).to_bytes(2, "little"), word(1001)
    try:
        assert await bus.read(1, POS.address, 2) is None
        answers = [await bus.read(1, reg.address, 2) for reg in (MODEL, POS) * 4]
    finally:
        await bus.close()
    assert answers == [model, pos] * 4
    failures = bus.stats.failures
    assert failures["timeout"] == 1
    # Normally the late reply arrives inside the second exchange (a duplicate); on a
    # stalled machine it may land just before it (stray bytes): either way it is seen.
    assert set(failures) <= {"timeout", "duplicate", "stray_bytes"} and len(failures) == 2


# -- retries -------------------------------------------------------------------------


async def test_retries_are_bounded() -> None:
    sim = make_sim(1)
    async with bus_on(sim, retries=2) as (bus, link):
        assert await bus.read(9, POS.address, 2) is None
        assert link.sent == [pr.read(9, POS.address, 2)] * 3
        assert bus.stats.failures["retry"] == 2
        assert bus.stats.failures["timeout"] == 3


async def test_a_retry_recovers_a_dropped_reply() -> None:
    sim = make_sim(1)
    sim.inject("drop", count=1)
    async with bus_on(sim, retries=2) as (bus, link):
        assert value(await bus.read(1, POS.address, 2)) == 1001
        assert len(link.sent) == 2
        assert bus.stats.failures == {"timeout": 1, "retry": 1}


async def test_a_sync_read_retry_asks_only_the_missing_servos() -> None:
    sim = make_sim(*IDS)
    sim.kill(2)
    async with bus_on(sim) as (bus, link):
        result = await bus.sync_read(IDS, POS.address, 2, retries=2)
        assert result.missing == [2] and sorted(result.data) == [1, 3]
        assert link.sent == [
            pr.sync_read(POS.address, 2, IDS),
            pr.sync_read(POS.address, 2, [2]),
            pr.sync_read(POS.address, 2, [2]),
        ]
        assert bus.stats.failures == {"timeout": 3, "retry": 2}


# -- scheduling and shutdown ------------------------------------------------------------


async def in_flight(link: NullModemLink) -> None:
    """Wait until the owner task has sent the first request (which then awaits its deadline)."""
    sent = asyncio.Event()
    write = link.write

    def spy(data: bytes) -> None:
        write(data)
        sent.set()

    link.write = spy  # type: ignore[method-assign]
    if not link.sent:
        async with asyncio.timeout(5):
            await sent.wait()
    assert len(link.sent) == 1


async def test_control_requests_overtake_queued_service_requests() -> None:
    sim = make_sim(*IDS)
    async with bus_on(sim, reply_margin_s=0.2, retries=0) as (bus, link):
        running = asyncio.create_task(bus.read(9, POS.address, 2))  # nobody there: waits
        await in_flight(link)
        service = asyncio.create_task(bus.ping(1, priority=PRIORITY_SERVICE))
        control = asyncio.create_task(bus.sync_read(IDS, POS.address, 2))
        await asyncio.sleep(0)  # both queued while the first exchange still waits
        assert len(link.sent) == 1
        assert await running is None
        assert await service and (await control).missing == []
        assert link.sent == [
            pr.read(9, POS.address, 2),
            pr.sync_read(POS.address, 2, IDS),  # queued second, sent first
            pr.ping(1),
        ]


async def test_priority_order_holds_for_many_queued_requests() -> None:
    sim = make_sim(*IDS)
    async with bus_on(sim, reply_margin_s=0.2, retries=0) as (bus, link):
        blocker = asyncio.create_task(bus.ping(9))
        await in_flight(link)
        prio = {1: PRIORITY_CONTROL, 3: PRIORITY_CONTROL, 2: PRIORITY_SERVICE}
        tasks = [
            asyncio.create_task(bus.read(i, POS.address, 2, priority=prio[i]))
            for i in (2, 1, 2, 3, 2, 1)
        ]
        await asyncio.gather(blocker, *tasks)
    ids = [p[2] for p in link.sent[1:]]  # FF FF ID ...
    # Control (odd ids) first, each class in arrival order.
    assert ids == [1, 3, 1, 2, 2, 2]


async def test_close_fails_queued_requests_and_never_hangs() -> None:
    sim = make_sim(*IDS)
    link = NullModemLink(answered_by(sim))
    bus = ServoBus(link, reply_margin_s=5.0)  # the running exchange would wait 5 s
    running = asyncio.create_task(bus.read(9, POS.address, 2))
    await in_flight(link)
    queued = [
        asyncio.create_task(bus.ping(1)),
        asyncio.create_task(bus.sync_read(IDS, POS.address, 2)),
        asyncio.create_task(bus.write(2, GOAL.address, word(5), priority=PRIORITY_CONTROL)),
    ]
    await asyncio.sleep(0)
    async with asyncio.timeout(1):
        await bus.close()
        results = await asyncio.gather(running, *queued, return_exceptions=True)
    assert all(isinstance(r, BusClosed) for r in results), results
    assert len(link.sent) == 1 and link.closed
    with pytest.raises(BusClosed):
        await bus.ping(1)
    async with asyncio.timeout(1):
        await bus.close()  # twice is fine


async def test_a_cancelled_caller_does_not_stall_the_bus() -> None:
    sim = make_sim(*IDS)
    async with bus_on(sim, reply_margin_s=0.2, retries=0) as (bus, link):
        running = asyncio.create_task(bus.read(9, POS.address, 2))
        await in_flight(link)
        doomed = asyncio.create_task(bus.ping(1))
        await asyncio.sleep(0)
        doomed.cancel()
        assert value(await bus.read(2, POS.address, 2)) == 1002
        assert await running is None
        assert pr.ping(1) not in link.sent  # a request nobody waits for is not sent


async def test_a_broken_link_fails_the_request_not_the_bus() -> None:
    sim = make_sim(1)
    async with bus_on(sim) as (bus, link):
        link.closed = True  # write() now raises, as a yanked USB adapter would
        with pytest.raises(ConnectionError):
            await bus.ping(1)
        assert bus.stats.failures["link"] == 1
        link.closed = False
        assert await bus.ping(1)


# -- no fault ever escapes ---------------------------------------------------------------


async def exercise(bus: ServoBus, rounds: int, *, exact: bool = True) -> None:
    """Mixed traffic; every answer must be either right or reported missing.

    ``exact=False`` for arbitrary byte mutations: an 8-bit checksum lets one in 256
    mangled packets through, so only the shape of the answers can be promised.
    """
    for n in range(rounds):
        result = await bus.sync_read(IDS, POS.address, 2)
        assert set(result.data) | set(result.missing) == set(IDS)
        assert not set(result.data) & set(result.missing)
        assert all(len(d) == 2 for d in result.data.values())
        got = await bus.read(1 + n % 3, MODEL.address, 2)
        if exact:
            assert got in (None, (777).to_bytes(2, "little"))
        else:
            assert got is None or len(got) == 2
        await bus.ping(2)
        await bus.write(3, GOAL.address, word(1003))
        await bus.sync_write(GOAL.address, 2, {i: word(1000 + i) for i in IDS})


async def expect_whole(bus: ServoBus) -> None:
    bus.margin = 0.05  # the faults are gone: only a stalled machine could time out now
    result = await bus.sync_read(IDS, POS.address, 2)
    assert {i: value(d) for i, d in result.data.items()} == {1: 1001, 2: 1002, 3: 1003}


@pytest.mark.parametrize("kind", ["drop", "corrupt", "truncate", "garbage", "delay"])
async def test_no_fault_kind_escapes_and_the_bus_recovers(kind: str) -> None:
    sim = make_sim(*IDS)
    # handle() cannot wait, so "delay" is a no-op here; the pty tests give it teeth.
    sim.inject(kind, rate=0.5, seconds=0.0)
    async with bus_on(sim, reply_margin_s=0.02) as (bus, _link):
        await exercise(bus, 8)
        if kind != "delay":
            assert bus.stats.failures, "the fault should have shown in the counters"
        sim.clear_faults()
        await expect_whole(bus)


mutation = st.one_of(
    st.tuples(st.just("flip"), st.integers(0, 63), st.integers(1, 255)),
    st.tuples(st.just("cut"), st.integers(0, 63), st.just(0)),
    st.tuples(st.just("insert"), st.integers(0, 63), st.integers(0, 255)),
    st.tuples(st.just("drop"), st.just(0), st.just(0)),
    st.tuples(st.just("split"), st.integers(0, 63), st.just(0)),
)


def mutate(plan: list[tuple[str, int, int]]) -> Manipulator:
    """Apply the next planned mutation to each reply chunk, cycling through the plan."""
    step = itertools.count()

    def manipulate(reply: bytes) -> list[bytes]:
        what, at, arg = plan[next(step) % len(plan)]
        at %= len(reply) + 1
        if what == "flip" and at < len(reply):
            return [reply[:at] + bytes((reply[at] ^ arg,)) + reply[at + 1 :]]
        if what == "cut":
            return [reply[:at]]
        if what == "insert":
            return [reply[:at] + bytes((arg,)) + reply[at:]]
        if what == "drop":
            return []
        if what == "split":
            return [reply[:at], reply[at:]]
        return [reply]

    return manipulate


@settings(
    max_examples=40,
    deadline=None,
    database=None,  # no .hypothesis/ directory in the work tree
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(plan=st.lists(mutation, min_size=1, max_size=8))
def test_random_byte_mutations_never_raise(plan: list[tuple[str, int, int]]) -> None:
    async def run() -> None:
        sim = make_sim(*IDS)
        async with bus_on(sim, manipulator=mutate(plan), reply_margin_s=0.002) as (bus, link):
            await exercise(bus, 3, exact=False)
            link.manipulator = None
            await expect_whole(bus)

    asyncio.run(run())


# -- waiting is free --------------------------------------------------------------------


async def test_waiting_for_a_dead_servo_costs_no_cpu() -> None:
    sim = make_sim(1)
    async with bus_on(sim, reply_margin_s=0.2, retries=0) as (bus, _link):
        await bus.ping(1)  # warm up: the owner task exists, imports are done
        wall0, cpu0 = time.monotonic(), time.process_time()
        assert await bus.read(9, POS.address, 2) is None
        wall, cpu = time.monotonic() - wall0, time.process_time() - cpu0
    assert wall >= 0.19  # it really waited for the deadline...
    assert cpu < 0.3 * wall, f"{cpu * 1000:.1f} ms CPU in {wall * 1000:.1f} ms"  # ...asleep
