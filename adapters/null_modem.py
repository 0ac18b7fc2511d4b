"""An in-process ByteLink wired straight to a responder: fast, deterministic bus tests.

pymodbus's NullModem idea: no pty, no serial driver, but the same bytes. A
``manipulator`` hook sees every chunk on its way back to the bus client and may
split it, corrupt it or drop it, so framing and recovery are tested without
timing luck. The pty path (adapters/sim/pty_server.py) is for end-to-end tests.
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable, Sequence

from lupin import protocol
from lupin.protocol import Packet

Responder = Callable[[Packet, float], Sequence[bytes]]
# Returns the chunks to deliver instead of ``data`` (empty list = drop it).
Manipulator = Callable[[bytes], Sequence[bytes]]


class NullModemLink:
    """ByteLink whose far end is a function from instruction packets to reply bytes."""

    def __init__(
        self,
        responder: Responder,
        *,
        baud: int = 1_000_000,
        manipulator: Manipulator | None = None,
        clock: Callable[[], float] | None = None,
        latency_s: float = 0.0,
    ) -> None:
        self.baud = baud
        self.responder = responder
        self.manipulator = manipulator
        self.latency_s = latency_s
        self.sent: list[bytes] = []
        self._rx = bytearray()
        self._pending: deque[bytes] = deque()  # chunks due, delivered one per loop pass
        self._dripping = False
        self._callback: Callable[[bytes], None] = lambda _data: None
        self._clock = clock
        self.closed = False

    def set_receiver(self, callback: Callable[[bytes], None]) -> None:
        self._callback = callback

    def write(self, data: bytes) -> None:
        if self.closed:
            raise ConnectionError("null modem closed")
        self.sent.append(bytes(data))
        self._rx += data
        loop = asyncio.get_running_loop()
        now = self._clock() if self._clock else loop.time()
        while True:
            consumed, pkt = protocol.decode(self._rx)
            del self._rx[:consumed]
            if pkt is None:
                break
            chunks: list[bytes] = []
            for reply in self.responder(pkt, now):
                out = self.manipulator(reply) if self.manipulator else [reply]
                chunks += (bytes(c) for c in out)
            if not chunks:
                continue
            # One timer per request keeps its chunks in order (equal-time timers are not).
            if self.latency_s:
                loop.call_later(self.latency_s, self._enqueue, chunks)
            else:
                loop.call_soon(self._enqueue, chunks)

    def _enqueue(self, chunks: list[bytes]) -> None:
        self._pending.extend(chunks)
        if not self._dripping:
            self._dripping = True
            asyncio.get_running_loop().call_soon(self._drip)

    def _drip(self) -> None:
        # One chunk per event-loop pass, so the client really runs between the
        # pieces of a split reply; delivered all in one pass, a split is invisible.
        chunk = self._pending.popleft()
        try:
            if not self.closed:
                self._callback(chunk)  # first, so a task it wakes runs before the next chunk
        finally:
            if self._pending:
                asyncio.get_running_loop().call_soon(self._drip)
            else:
                self._dripping = False

    async def close(self) -> None:
        self.closed = True
