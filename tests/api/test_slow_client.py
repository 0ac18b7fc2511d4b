"""A stalled WebSocket client costs nothing: not the control tick, not the other clients.

The stalled client is a raw socket that completes the upgrade and never reads
again. Its server-side socket and transport get tiny buffers, so the server's
send really does block within the test (on loopback the kernel would otherwise
buffer megabytes). The hard assertions are on counts and structure; the tick
timing is compared with a baseline window, taking the best of a few windows so
a burst of load from elsewhere on the machine does not fail the test.
"""

from __future__ import annotations

import asyncio
import base64
import os
import socket
from dataclasses import dataclass

import aiohttp

from lupin.api import ApiServer
from lupin.api.ws import Connection, WsSettings
from lupin.daemon import Daemon
from lupintest.harness import wait_for

from .conftest import start_api

WINDOW_S = 1.5
STALLED_WINDOWS = 3


@dataclass
class Window:
    frames: int  # state frames the reading client got
    ticks: int
    overruns: int
    p99: float  # tick period, s


def p99(values: list[float]) -> float:
    ordered = sorted(values)
    return ordered[int(0.99 * (len(ordered) - 1))]


async def read_forever(ws: aiohttp.ClientWebSocketResponse, arrivals: list[float]) -> None:
    """Keep reading (so pings are answered), noting when each state frame arrives."""
    loop = asyncio.get_running_loop()
    async for msg in ws:
        if msg.type is aiohttp.WSMsgType.TEXT and msg.json()["type"] == "state":
            arrivals.append(loop.time())


async def measure(daemon: Daemon, arrivals: list[float]) -> Window:
    assert daemon.loop is not None
    stats = daemon.loop.stats
    loop = asyncio.get_running_loop()
    ticks0, overruns0 = stats.ticks, stats.overruns
    stats.periods.clear()
    start = loop.time()
    await asyncio.sleep(WINDOW_S)
    frames = sum(1 for t in arrivals if t >= start)
    return Window(
        frames, stats.ticks - ticks0, stats.overruns - overruns0, p99(list(stats.periods))
    )


async def stalled_client(url: str) -> socket.socket:
    """Upgrade to a WebSocket by hand, then never read again."""
    host, port = url.removeprefix("http://").split(":")
    loop = asyncio.get_running_loop()
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.setblocking(False)
    await loop.sock_connect(sock, (host, int(port)))
    key = base64.b64encode(os.urandom(16)).decode()
    request = (
        f"GET /api/ws HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
        f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n"
    )
    await loop.sock_sendall(sock, request.encode())
    head = await asyncio.wait_for(loop.sock_recv(sock, 1024), 2.0)
    assert head.startswith(b"HTTP/1.1 101"), head
    return sock


def shrink_buffers(conn: Connection) -> None:
    assert isinstance(conn.transport, asyncio.WriteTransport)
    conn.transport.get_extra_info("socket").setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
    conn.transport.set_write_buffer_limits(high=4096)


async def test_stalled_client_does_not_slow_the_tick_or_other_clients(
    http: aiohttp.ClientSession, daemon: Daemon
) -> None:
    # A long heartbeat: here the stalled client must stay connected (and stalled)
    # for the whole measurement; test_ws covers the heartbeat closing dead clients.
    api = await start_api(daemon, ws=WsSettings(heartbeat_s=60.0))
    try:
        await check_stall(http, api, daemon)
    finally:
        await api.stop()


async def check_stall(http: aiohttp.ClientSession, api: ApiServer, daemon: Daemon) -> None:
    arrivals: list[float] = []
    stalled_windows: list[Window] = []
    async with http.ws_connect(api.url + "/api/ws") as reader:
        await reader.receive_json(timeout=2)  # hello
        reading = asyncio.create_task(read_forever(reader, arrivals))
        await wait_for(lambda: len(api.hub.connections) == 1)
        (reader_conn,) = api.hub.connections
        baseline = await measure(daemon, arrivals)

        sock = await stalled_client(api.url)
        try:
            await wait_for(lambda: len(api.hub.connections) == 2)
            (stalled,) = [c for c in api.hub.connections if c is not reader_conn]
            shrink_buffers(stalled)
            # The stall is real: the server's writer for it is stuck, and newer states
            # replace the unsent one in its one-frame slot instead of queueing.
            await wait_for(lambda: stalled.outbox.replaced >= 5, 10.0)
            assert isinstance(stalled.transport, asyncio.WriteTransport)
            assert stalled.transport.get_write_buffer_size() <= 2 * WsSettings().writer_limit
            for _ in range(STALLED_WINDOWS):
                sent, replaced = stalled.outbox.sent, stalled.outbox.replaced
                stalled_windows.append(await measure(daemon, arrivals))
                assert stalled.outbox.sent == sent  # it really received nothing meanwhile
                assert stalled.outbox.replaced - replaced >= 10 * WINDOW_S  # still offered
                assert stalled.outbox.state is not None and not stalled.outbox.replies
        finally:
            sock.close()
        await reader.close()
        await reading

    # Counts: the reading client keeps ~20 Hz and the tick keeps ticking, in every window.
    for window in (baseline, *stalled_windows):
        assert window.frames >= 10 * WINDOW_S, window
        assert window.ticks >= 50 * WINDOW_S, window
    # Timing: at least one stalled window is as good as the baseline, give or take.
    best = min(stalled_windows, key=lambda w: (w.overruns, w.p99))
    assert best.overruns <= baseline.overruns + 2, (baseline, stalled_windows)
    assert best.p99 <= max(2 * baseline.p99, baseline.p99 + 0.005), (baseline, stalled_windows)
    await wait_for(lambda: not api.hub.connections, 5.0)


async def test_stop_is_prompt_even_with_a_stalled_client(daemon: Daemon) -> None:
    # lupin run stops the API before the daemon's safe stop: a client whose close
    # frame can never be delivered must not hold the safe stop up.
    api = await start_api(daemon)
    loop = asyncio.get_running_loop()
    sock = await stalled_client(api.url)
    try:
        await wait_for(lambda: len(api.hub.connections) == 1)
        (conn,) = api.hub.connections
        shrink_buffers(conn)
        await wait_for(lambda: conn.outbox.replaced >= 2, 10.0)
        start = loop.time()
        await api.stop()
        assert loop.time() - start < 2.0
        assert not api.hub.connections
    finally:
        sock.close()
        await api.stop()
