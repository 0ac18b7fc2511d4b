"""The simulator on a pty, end to end: a pyserial-asyncio client and the vendor SDK as clients."""

from __future__ import annotations

import asyncio
import contextlib
import os
import time
from collections.abc import AsyncIterator, Iterator

import pytest
import scservo_sdk as sdk
import serial_asyncio

from lupin import control_table as ct
from lupin import protocol as pr
from lupin.protocol import Packet
from lupin_adapters.sim.bus import SimServoSpec, SimulatedBus, build_sim_bus
from lupin_adapters.sim.pty_server import PtySimServer, serve

pytestmark = pytest.mark.asyncio

REG = ct.REGISTERS
POS = REG["present_position"]
GOAL = REG["goal_position"]

Stream = tuple[asyncio.StreamReader, asyncio.StreamWriter]


def open_fds() -> set[str]:
    return set(os.listdir("/proc/self/fd"))


@pytest.fixture(autouse=True)
def no_leaked_fds() -> Iterator[None]:
    before = open_fds()
    yield
    leaked = open_fds() - before
    # An fd number may be reused for something harmless; a pty is not harmless.
    ptys = [fd for fd in leaked if "pt" in _target(fd)]
    assert not ptys, f"leaked pty fds: {ptys}"


def _target(fd: str) -> str:
    try:
        return os.readlink(f"/proc/self/fd/{fd}")
    except OSError:
        return ""


def _path(server: PtySimServer) -> str:
    """The server's path (entering ``async with server`` has started it)."""
    assert server.path is not None
    return server.path


def make_bus(*ids: int) -> SimulatedBus:
    return build_sim_bus([SimServoSpec(i, position=1000 + i) for i in ids])


@contextlib.asynccontextmanager
async def client(path: str) -> AsyncIterator[Stream]:
    reader, writer = await serial_asyncio.open_serial_connection(url=path, baudrate=1_000_000)
    try:
        yield reader, writer
    finally:
        writer.close()
        await writer.wait_closed()


async def read_packets(reader: asyncio.StreamReader, n: int, within: float = 1.0) -> list[Packet]:
    buf = bytearray()
    out: list[Packet] = []
    async with asyncio.timeout(within):
        while len(out) < n:
            used, packet = pr.decode(buf)
            del buf[:used]
            if packet is not None:
                out.append(packet)
            else:
                buf += await reader.read(256)
    return out


async def ask(stream: Stream, request: bytes, replies: int = 1) -> list[Packet]:
    reader, writer = stream
    writer.write(request)
    await writer.drain()
    return await read_packets(reader, replies)


async def test_asyncio_client_round_trip() -> None:
    bus = make_bus(1, 2)
    async with PtySimServer(bus) as server:
        assert server.path is not None and server.path.startswith("/dev/")
        async with client(server.path) as stream:
            assert await ask(stream, pr.ping(2)) == [Packet(2, 0)]
            (reply,) = await ask(stream, pr.read(1, POS.address, 2))
            assert ct.decode_value(POS, reply.params) == 1001
            await ask(stream, pr.write(1, GOAL.address, ct.encode_value(GOAL, 1001)))
            await ask(stream, pr.write(1, 40, b"\x01"))
            assert bus[1].torque


async def test_split_and_noisy_requests_are_answered() -> None:
    async with PtySimServer(make_bus(1)) as server, client(server.path or "") as stream:
        reader, writer = stream
        request = b"\x00\x13\xff" + pr.ping(1)
        for byte in request:  # one byte at a time, as a slow line would deliver it
            writer.write(bytes((byte,)))
            await writer.drain()
            await asyncio.sleep(0.002)
        assert await read_packets(reader, 1) == [Packet(1, 0)]


async def test_sync_read_skips_a_dead_servo_and_keeps_the_others() -> None:
    bus = make_bus(1, 2, 3)
    bus.kill(2)
    async with PtySimServer(bus) as server, client(server.path or "") as stream:
        replies = await ask(stream, pr.sync_read(POS.address, 2, [1, 2, 3]), replies=2)
        assert [(p.id, ct.decode_value(POS, p.params)) for p in replies] == [(1, 1001), (3, 1003)]


async def test_client_can_close_and_reopen() -> None:
    async with PtySimServer(make_bus(1)) as server:
        for _ in range(3):
            async with client(server.path or "") as stream:
                assert await ask(stream, pr.ping(1)) == [Packet(1, 0)]


def _sdk_session(path: str) -> dict[str, object]:
    """A blocking vendor-SDK session (runs in a thread while the server runs in the loop)."""
    port = sdk.PortHandler(path)
    assert port.openPort()
    try:
        ph = sdk.PacketHandler(0)
        out: dict[str, object] = {"ping": ph.ping(port, 1)}
        out["read"] = ph.read2ByteTxRx(port, 2, POS.address)
        out["unlock"] = ph.write1ByteTxRx(port, 1, REG["lock"].address, 0)
        out["torque"] = ph.write1ByteTxRx(port, 1, 40, 1)
        writer = sdk.GroupSyncWrite(port, ph, GOAL.address, 2)
        for sid, goal in ((1, 1500), (2, 2500)):
            writer.addParam(sid, list(ct.encode_value(GOAL, goal)))
        out["sync_write"] = writer.txPacket()
        reader = sdk.GroupSyncRead(port, ph, GOAL.address, 2)
        for sid in (1, 2):
            reader.addParam(sid)
        out["sync_read"] = reader.txRxPacket()
        out["goals"] = [reader.getData(sid, GOAL.address, 2) for sid in (1, 2)]
        return out
    finally:
        port.closePort()


async def test_vendor_sdk_as_a_client() -> None:
    bus = make_bus(1, 2)
    async with PtySimServer(bus) as server:
        out = await asyncio.to_thread(_sdk_session, server.path or "")
    assert out["ping"] == (777, sdk.COMM_SUCCESS, 0)
    assert out["read"] == (1002, sdk.COMM_SUCCESS, 0)
    assert out["unlock"] == (sdk.COMM_SUCCESS, 0)
    assert out["torque"] == (sdk.COMM_SUCCESS, 0)
    assert out["sync_write"] == sdk.COMM_SUCCESS
    assert out["sync_read"] == sdk.COMM_SUCCESS
    assert out["goals"] == [1500, 2500]
    assert bus[1].torque and bus[1].get("lock") == 0
    # The SDK's packets, as the simulator received them, are the codec's packets.
    sent = [p.encode() for _, p in bus.received]
    assert pr.ping(1) in sent and pr.read(2, POS.address, 2) in sent
    assert pr.sync_read(GOAL.address, 2, [1, 2]) in sent


async def test_wire_pacing_adds_line_time_and_return_delay() -> None:
    bus = make_bus(1)
    bus[1].set("return_delay", 250)  # 500 µs
    server = PtySimServer(bus, baud=9600, wire_pacing=True)
    async with server, client(_path(server)) as stream:
        start = time.monotonic()
        await ask(stream, pr.ping(1))
        elapsed = time.monotonic() - start
    # 6-byte request + 6-byte reply at 10 bits a byte, 9600 baud: 12.5 ms, + 0.5 ms.
    assert elapsed >= 0.012


async def test_replies_keep_their_order_under_pacing() -> None:
    server = PtySimServer(make_bus(1, 2, 3), baud=115_200, wire_pacing=True)
    async with server, client(_path(server)) as stream:
        replies = await ask(stream, pr.sync_read(POS.address, 2, [3, 1, 2]), replies=3)
    assert [p.id for p in replies] == [3, 1, 2]


async def test_delay_fault_holds_the_line() -> None:
    bus = make_bus(1, 2)
    bus.inject("delay", ids=[1], seconds=0.2, count=1)
    async with PtySimServer(bus) as server, client(server.path or "") as stream:
        reader, writer = stream
        start = time.monotonic()
        writer.write(pr.ping(1) + pr.ping(2))
        first, second = await read_packets(reader, 2)
        assert time.monotonic() - start >= 0.19
        assert (first.id, second.id) == (1, 2)  # one line: the late reply blocks the next


async def test_physics_runs_with_no_traffic() -> None:
    bus = build_sim_bus([SimServoSpec(1, position=2000, gravity=50, sag_rate=1000)])
    async with PtySimServer(bus):
        await asyncio.sleep(0.3)
        assert bus[1].present_position < 1900  # limp and sagging, nobody asked


async def test_injected_clock_timestamps_the_log() -> None:
    now = [100.0]
    bus = make_bus(1)
    server = PtySimServer(bus, clock=lambda: now[0])
    async with server, client(_path(server)) as stream:
        await ask(stream, pr.ping(1))
        now[0] = 105.0
        await ask(stream, pr.ping(1))
    assert [t for t, _ in bus.received] == [100.0, 105.0]


async def test_serve_prints_the_path_first_and_runs_until_cancelled() -> None:
    lines: list[str] = []
    printed = asyncio.Event()

    def print_path(path: str) -> None:
        lines.append(path)
        printed.set()

    task = asyncio.create_task(serve(make_bus(1), print_path=print_path))
    async with asyncio.timeout(2):
        await printed.wait()
    assert lines[0].startswith("/dev/")
    async with client(lines[0]) as stream:
        assert await ask(stream, pr.ping(1)) == [Packet(1, 0)]
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task


async def test_close_is_idempotent_and_start_once() -> None:
    server = PtySimServer(make_bus(1))
    await server.start()
    with pytest.raises(RuntimeError):
        await server.start()
    await server.close()
    await server.close()
