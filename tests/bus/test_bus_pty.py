"""ServoBus over the real path: PtySimServer, SerialLink on pyserial-asyncio, the bus client.

The same codec, transport and scheduler as on a robot; only the far end of the
wire is simulated. Every fault kind the simulator can inject goes over the pty,
and the single-opener guard is checked against real second processes.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import sys
import time
from collections.abc import AsyncIterator, Iterator

import pytest

from lupin import control_table as ct
from lupin.bus import ServoBus
from lupin_adapters.serial_link import PortBusy, SerialLink
from lupin_adapters.sim.bus import SimServoSpec, SimulatedBus, build_sim_bus
from lupin_adapters.sim.pty_server import PtySimServer

REG = ct.REGISTERS
POS = REG["present_position"]
GOAL = REG["goal_position"]
MODEL = REG["model"]
BAUD = 1_000_000
IDS = (1, 2, 3)


def make_sim(*ids: int) -> SimulatedBus:
    return build_sim_bus([SimServoSpec(i, position=1000 + i) for i in ids])


def word(value: int) -> bytes:
    return ct.encode_value(GOAL, value)


def values(data: dict[int, bytes]) -> dict[int, int]:
    return {i: ct.decode_value(POS, d) for i, d in data.items()}


def _fd_target(fd: str) -> str:
    try:
        return os.readlink(f"/proc/self/fd/{fd}")
    except OSError:
        return ""


@pytest.fixture(autouse=True)
def no_leaked_ptys() -> Iterator[None]:
    before = set(os.listdir("/proc/self/fd"))
    yield
    leaked = [fd for fd in set(os.listdir("/proc/self/fd")) - before if "pt" in _fd_target(fd)]
    assert not leaked, f"leaked pty fds: {leaked}"


@contextlib.asynccontextmanager
async def serving(sim: SimulatedBus, *, wire_pacing: bool = False) -> AsyncIterator[str]:
    server = PtySimServer(sim, baud=BAUD, wire_pacing=wire_pacing)
    path = await server.start()
    try:
        yield path
    finally:
        await server.close()


@contextlib.asynccontextmanager
async def pty_bus(
    sim: SimulatedBus,
    *,
    wire_pacing: bool = False,
    retries: int = 1,
    reply_margin_s: float = 0.1,  # generous: a busy CI machine must not fake a timeout
) -> AsyncIterator[ServoBus]:
    async with serving(sim, wire_pacing=wire_pacing) as path:
        link = await SerialLink.open(path, BAUD)
        bus = ServoBus(link, reply_margin_s=reply_margin_s, retries=retries)
        try:
            yield bus
        finally:
            await bus.close()


async def read_both(bus: ServoBus) -> tuple[dict[int, int], dict[int, bytes]]:
    """Two sync reads of the same shape (2 bytes) but different registers."""
    pos = await bus.sync_read(IDS, POS.address, 2)
    model = await bus.sync_read(IDS, MODEL.address, 2)
    return values(pos.data), model.data


async def assert_in_step(bus: ServoBus, rounds: int = 10) -> None:
    """Whole answers, each to its own question: no reply taken for another's."""
    bus.margin = 0.1  # the faults are gone: only a stalled machine could time out now
    for _ in range(rounds):
        pos, model = await read_both(bus)
        assert pos == {1: 1001, 2: 1002, 3: 1003}
        assert model == dict.fromkeys(IDS, (777).to_bytes(2, "little"))


# -- the happy path --------------------------------------------------------------


@pytest.mark.parametrize("wire_pacing", [False, True], ids=["immediate", "paced"])
async def test_every_request_kind_over_the_pty(wire_pacing: bool) -> None:
    sim = make_sim(*IDS)
    async with pty_bus(sim, wire_pacing=wire_pacing) as bus:
        assert await bus.ping(3)
        assert await bus.read(2, POS.address, 2) == word(1002)
        assert await bus.write(1, GOAL.address, word(1500))
        await bus.sync_write(GOAL.address, 2, {2: word(1600), 3: word(1700)})
        result = await bus.sync_read(IDS, GOAL.address, 2)
        assert values(result.data) == {1: 1500, 2: 1600, 3: 1700}
        assert not bus.stats.failures
        assert bus.stats.bytes_in > 0 and bus.stats.bytes_out > 0
    assert [sim[i].get("goal_position") for i in IDS] == [1500, 1600, 1700]


async def test_a_paced_transaction_takes_at_least_its_wire_time() -> None:
    sim = build_sim_bus([SimServoSpec(i) for i in range(1, 9)])
    ids = list(range(1, 9))
    async with pty_bus(sim, wire_pacing=True) as bus:
        await bus.ping(1)  # warm up
        n = 20
        start = time.monotonic()
        for _ in range(n):
            result = await bus.sync_read(ids, POS.address, 6)
            assert result.missing == []
        elapsed = time.monotonic() - start
        # 16-byte request + 8 replies of 12 bytes at 10 bits a byte: 1.12 ms each.
        wire = bus.wire_time(16 + 8 * 12)
        assert wire == pytest.approx(0.00112)
        assert elapsed >= n * wire
        assert not bus.stats.failures


# -- every fault the simulator injects, over the pty --------------------------------


@pytest.mark.parametrize("kind", ["drop", "corrupt", "truncate", "garbage"])
async def test_a_faulty_reply_costs_one_servo_and_the_bus_recovers(kind: str) -> None:
    sim = make_sim(*IDS)
    fault = sim.inject(kind, ids=[2], count=3)
    async with pty_bus(sim, retries=0) as bus:
        results = [await bus.sync_read(IDS, POS.address, 2) for _ in range(3)]
        assert fault.fired == 3
        failures = bus.stats.failures
        for result in results:
            if kind == "garbage":  # noise before a whole reply costs nothing
                assert values(result.data) == {1: 1001, 2: 1002, 3: 1003}
            else:
                assert values(result.data) == {1: 1001, 3: 1003} and result.missing == [2]
        if kind == "drop":
            assert failures == {"timeout": 3}
        elif kind == "garbage":
            assert set(failures) == {"garbled"}
        else:
            assert failures["timeout"] + failures["truncated"] == 3
            assert failures["garbled"] > 0
        await assert_in_step(bus)  # the fault has run out: whole again


async def test_a_delayed_reply_is_counted_and_the_bus_gets_back_in_step() -> None:
    """A reply 400 ms late holds the line (replies queue behind it), then all arrive at once.

    Status packets name no request: without a resync after that burst, every later
    exchange takes the previous exchange's replies for its own, for good.
    """
    sim = make_sim(*IDS)
    sim.inject("delay", ids=[2], seconds=0.4, count=1)
    async with pty_bus(sim, wire_pacing=True, retries=0) as bus:
        first = await bus.sync_read(IDS, POS.address, 2)
        assert first.missing == [2, 3]  # 3 queues behind 2 on the one line
        # Keep asking through the delay, alternating two registers of the same size.
        for _ in range(6):
            await read_both(bus)
        failures = bus.stats.failures
        assert failures["timeout"] >= 2
        assert failures["stray_bytes"] + failures["duplicate"] > 0  # the burst was seen
        await assert_in_step(bus)


async def test_a_dead_servo_is_reported_missing_until_revived() -> None:
    sim = make_sim(*IDS)
    async with pty_bus(sim, retries=0) as bus:
        sim.kill(3)
        result = await bus.sync_read(IDS, POS.address, 2)
        assert values(result.data) == {1: 1001, 2: 1002} and result.missing == [3]
        assert not await bus.ping(3)
        assert bus.stats.failures["timeout"] == 2
        sim.revive(3)
        await assert_in_step(bus)


async def test_servo_error_bits_over_the_pty() -> None:
    sim = make_sim(*IDS)
    sim.set_error(1, 1)  # under-voltage
    async with pty_bus(sim) as bus:
        result = await bus.sync_read(IDS, POS.address, 2)
        assert result.errors == {1: 1} and result.missing == []
        assert bus.stats.failures["servo_error"] == 1
        sim.set_error(1, 0)
        assert (await bus.sync_read(IDS, POS.address, 2)).errors == {}


async def test_a_storm_of_every_fault_kind_never_raises() -> None:
    sim = make_sim(*IDS)
    for kind in ("drop", "corrupt", "truncate", "garbage"):
        sim.inject(kind, rate=0.2)
    sim.inject("delay", rate=0.1, seconds=0.01)
    async with pty_bus(sim, wire_pacing=True, reply_margin_s=0.01) as bus:
        for n in range(25):
            result = await bus.sync_read(IDS, POS.address, 2)
            assert set(result.data) | set(result.missing) == set(IDS)
            await bus.read(1 + n % 3, MODEL.address, 2)
            await bus.write(1, GOAL.address, word(1001))
            await bus.sync_write(GOAL.address, 2, {i: word(1000 + i) for i in IDS})
        kinds = set(bus.stats.failures)
        assert {"timeout", "garbled"} <= kinds, kinds
        sim.clear_faults()
        await asyncio.sleep(0.05)  # let the last delayed reply land
        await assert_in_step(bus)


# -- the single-opener guard --------------------------------------------------------

HOLD = (
    "import serial, sys, time\n"
    "port = serial.Serial(sys.argv[1], 1_000_000)\n"
    "print('holding', flush=True)\n"
    "time.sleep(60)\n"
)
CHECK = (
    "import sys\n"
    "from lupin_adapters.serial_link import PortBusy, check_port_free\n"
    "try:\n"
    "    check_port_free(sys.argv[1])\n"
    "except PortBusy as exc:\n"
    "    print(exc)\n"
    "    sys.exit(3)\n"
    "print('free')\n"
)


@contextlib.asynccontextmanager
async def holder(path: str) -> AsyncIterator[int]:
    """Another process holding the port open for writing, as a stray bench tool would."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-c", HOLD, path, stdout=asyncio.subprocess.PIPE
    )
    try:
        assert proc.stdout is not None
        async with asyncio.timeout(10):
            assert await proc.stdout.readline() == b"holding\n"
        yield proc.pid
    finally:
        with contextlib.suppress(ProcessLookupError):
            proc.kill()
        await proc.communicate()


async def check_in_another_process(path: str) -> tuple[int, str]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-c", CHECK, path, stdout=asyncio.subprocess.PIPE
    )
    async with asyncio.timeout(20):
        out, _ = await proc.communicate()
    assert proc.returncode is not None
    return proc.returncode, out.decode()


async def test_a_port_held_by_another_process_is_refused_naming_its_pid() -> None:
    sim = make_sim(1)
    async with serving(sim) as path, holder(path) as pid:
        with pytest.raises(PortBusy, match=rf"\bPID {pid}\b"):
            await SerialLink.open(path, BAUD)
    assert not sim.received  # refused before a single byte was sent


async def test_our_open_port_is_refused_to_another_process_naming_our_pid() -> None:
    async with serving(make_sim(1)) as path:
        link = await SerialLink.open(path, BAUD)
        try:
            code, out = await check_in_another_process(path)
            assert code == 3, out
            assert f"PID {os.getpid()} " in out
        finally:
            await link.close()
        # Closed: free again.
        assert await check_in_another_process(path) == (0, "free\n")


async def test_the_simulators_own_read_only_handle_is_not_a_holder() -> None:
    async with serving(make_sim(1)) as path:
        # The server keeps a read-only slave fd open; nobody else has the port.
        assert any(_fd_target(fd) == path for fd in os.listdir("/proc/self/fd"))
        assert await check_in_another_process(path) == (0, "free\n")


async def test_a_second_open_in_this_process_is_refused_by_the_lock() -> None:
    async with serving(make_sim(1)) as path:
        first = await SerialLink.open(path, BAUD)
        try:
            with pytest.raises(PortBusy, match="lock"):
                await SerialLink.open(path, BAUD)
            bus = ServoBus(first)
            assert await bus.ping(1)  # the first opener is unharmed
        finally:
            await first.close()
