"""An in-process ByteLink wired straight to a responder: fast, deterministic bus tests.

pymodbus's NullModem idea: no pty, no serial driver, but the same bytes. A
``manipulator`` hook sees every chunk on its way back to the bus client and may
split it, corrupt it or drop it, so framing and recovery are tested without
timing luck. The pty path (adapters/sim/pty_server.py) is for end-to-end tests.
"""

from __future__ import annotations

import asyncio
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
            for reply in self.responder(pkt, now):
                chunks = self.manipulator(reply) if self.manipulator else [reply]
                for chunk in chunks:
                    if self.latency_s:
                        loop.call_later(self.latency_s, self._deliver, bytes(chunk))
                    else:
                        loop.call_soon(self._deliver, bytes(chunk))

    def _deliver(self, chunk: bytes) -> None:
        if not self.closed:
            self._callback(chunk)

    async def close(self) -> None:
        self.closed = True
