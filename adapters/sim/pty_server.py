"""The simulated bus served on a pty: a fake serial port that speaks the real Feetech protocol.

A client (the daemon's pyserial-asyncio transport, the vendor SDK, a bench
tool) opens the slave path like any serial device. The server owns the master
end with one ``loop.add_reader`` and no threads: the style guide's lesson from a
pty fake whose reader thread raced the test.

With ``wire_pacing`` a reply appears only after the time the request and the
reply would take on a real line (10 bits a byte at ``baud``) plus the servo's
return delay, so timing-sensitive code meets realistic latency. Without it
replies are immediate, which keeps the test suite fast.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import time
import tty
from collections import deque
from collections.abc import Callable
from types import TracebackType

from lupin.protocol import Packet, decode
from lupin_adapters.sim.bus import SimulatedBus

log = logging.getLogger(__name__)

PHYSICS_HZ = 100.0  # servos sag, heat and cool even when nobody is talking to them
MAX_PENDING_OUT = 1 << 20  # bytes held for a client that stopped reading


class PtySimServer:
    """Serve ``bus`` on a new pty until ``close()``."""

    def __init__(
        self,
        bus: SimulatedBus,
        *,
        baud: int = 1_000_000,
        wire_pacing: bool = False,
        clock: Callable[[], float] = time.monotonic,
        physics_hz: float = PHYSICS_HZ,
    ) -> None:
        self.bus = bus
        self.baud = baud
        self.wire_pacing = wire_pacing
        self.clock = clock
        self.physics_hz = physics_hz
        self.path: str | None = None
        self._master: int | None = None
        self._slave: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._rx = bytearray()
        self._out = bytearray()  # accepted for sending, not yet taken by the pty
        self._queue: deque[tuple[float, bytes]] = deque()  # (loop time due, bytes), in order
        self._timer: asyncio.TimerHandle | None = None
        self._line_free = 0.0  # loop time when the last queued reply has left the wire
        self._physics: asyncio.Task[None] | None = None

    async def start(self) -> str:
        """Open the pty and start serving; returns the slave path for clients (/dev/pts/N)."""
        if self._master is not None:
            raise RuntimeError("server already started")
        self._loop = asyncio.get_running_loop()
        master, slave = os.openpty()
        # Raw: no echo, no line editing, no CR/LF mangling, all 256 byte values pass.
        tty.setraw(slave)
        os.set_blocking(master, False)
        # Holding our own slave fd keeps the pty alive between clients, so the
        # master never reads EIO when a client closes and reopens the port. It is
        # re-opened read-only: the single-opener guard counts only writers (a
        # reader cannot corrupt the bus), so it does not mistake us for a client.
        self.path = os.ttyname(slave)
        keep = os.open(self.path, os.O_RDONLY | os.O_NOCTTY)
        os.close(slave)
        slave = keep
        self._master, self._slave = master, slave
        # Whatever clock drove the bus before (a test's fake one), ours starts now.
        self.bus.sync_clock(self.clock())
        self._loop.add_reader(master, self._on_readable)
        self._physics = asyncio.create_task(self._run_physics(), name="sim-physics")
        return self.path

    async def close(self) -> None:
        """Stop serving and release every fd, timer and task (safe to call twice)."""
        if self._master is None or self._loop is None:
            return
        master, slave = self._master, self._slave
        self._master = self._slave = None
        self._loop.remove_reader(master)
        self._loop.remove_writer(master)
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._queue.clear()
        self._out.clear()
        if self._physics is not None:
            self._physics.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._physics
            self._physics = None
        os.close(master)
        if slave is not None:
            os.close(slave)

    async def __aenter__(self) -> PtySimServer:
        await self.start()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()

    async def _run_physics(self) -> None:
        while True:
            await asyncio.sleep(1.0 / self.physics_hz)
            self.bus.advance(self.clock())

    # -- receiving --------------------------------------------------------------

    def _on_readable(self) -> None:
        assert self._master is not None
        try:
            chunk = os.read(self._master, 4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:  # should not happen while we hold the slave
            log.warning("sim pty read failed: %s", exc)
            return
        self._rx += chunk
        while True:
            used, packet = decode(self._rx)
            del self._rx[:used]
            if packet is None:
                return
            self._on_packet(packet)

    def _on_packet(self, packet: Packet) -> None:
        assert self._loop is not None
        replies = self.bus.respond(packet, self.clock())
        now = self._loop.time()
        # The request's own wire time: on a pty it arrived all at once.
        start = now + self._wire(len(packet.params) + 6)
        for reply in replies:
            # Replies share one line: each starts after the previous one has left.
            due = max(start, self._line_free) + reply.delay
            if self.wire_pacing:
                due += self._return_delay(reply.id) + self._wire(len(reply.data))
            self._line_free = start = due
            self._queue.append((due, reply.data))
        self._flush()

    def _wire(self, nbytes: int) -> float:
        return nbytes * 10 / self.baud if self.wire_pacing else 0.0

    def _return_delay(self, servo_id: int) -> float:
        try:
            return self.bus.servo(servo_id).get("return_delay") * 2e-6  # 2 µs units
        except KeyError:
            return 0.0

    # -- sending ----------------------------------------------------------------

    def _flush(self) -> None:
        """Send every reply that is due, in order; wake up again for the next one."""
        assert self._loop is not None
        self._timer = None
        now = self._loop.time()
        while self._queue and self._queue[0][0] <= now:
            self._send(self._queue.popleft()[1])
        if self._queue:
            # One timer for the head of the queue: timers due at the same instant
            # are not guaranteed to run in order, the queue is.
            self._timer = self._loop.call_at(self._queue[0][0], self._flush)

    def _send(self, data: bytes) -> None:
        if self._master is None:
            return
        if self._out:
            self._queue_out(data)
            return
        try:
            sent = os.write(self._master, data)
        except BlockingIOError:
            sent = 0
        except OSError as exc:
            log.warning("sim pty write failed: %s", exc)
            return
        if sent < len(data):
            self._queue_out(data[sent:])

    def _queue_out(self, data: bytes) -> None:
        assert self._loop is not None and self._master is not None
        if len(self._out) + len(data) > MAX_PENDING_OUT:
            log.warning("sim pty: client is not reading; dropping %d bytes", len(data))
            return
        if not self._out:
            self._loop.add_writer(self._master, self._on_writable)
        self._out += data

    def _on_writable(self) -> None:
        assert self._loop is not None and self._master is not None
        try:
            sent = os.write(self._master, self._out)
        except BlockingIOError:
            return
        except OSError as exc:
            log.warning("sim pty write failed: %s", exc)
            sent = len(self._out)
        del self._out[:sent]
        if not self._out:
            self._loop.remove_writer(self._master)


async def serve(
    bus: SimulatedBus,
    *,
    print_path: Callable[[str], object] = print,
    baud: int = 1_000_000,
    wire_pacing: bool = False,
    clock: Callable[[], float] = time.monotonic,
) -> None:
    """Serve ``bus`` on a pty, announce its path first, and run until cancelled."""
    server = PtySimServer(bus, baud=baud, wire_pacing=wire_pacing, clock=clock)
    path = await server.start()
    try:
        print_path(path)
        await asyncio.Event().wait()  # forever: the caller cancels us
    finally:
        await server.close()
