"""The asyncio Feetech bus client: one task owns the port, everything else asks it.

A serial bus has no arbitration: two writers interleave packets and both read
garbage (the bring-up seed). So exactly one task here writes to the link, taking
requests from a priority queue in which control-tick traffic goes first.

Waiting for a reply costs no CPU: bytes arrive through the link's callback into a
buffer, and the owner task sleeps on a future until either the bytes it expects
are there or a deadline derived from the wire time at the baud rate passes.

A short or corrupt reply is a failed read, never an exception; a SYNC_READ
returns every servo that answered even when one is missing or garbled.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import time
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

from lupin import protocol
from lupin.logs import Throttled
from lupin.protocol import Packet

log = logging.getLogger(__name__)

PRIORITY_CONTROL = 0
PRIORITY_SERVICE = 1

# Bits on the wire per byte: start + 8 data + stop.
BITS_PER_BYTE = 10
STATUS_OVERHEAD = 6  # FF FF ID LEN ERR .. CHK


class ByteLink(Protocol):
    """What a bus adapter provides: bytes out, bytes in through a callback."""

    baud: int

    def write(self, data: bytes) -> None: ...

    def set_receiver(self, callback: Callable[[bytes], None]) -> None: ...

    async def close(self) -> None: ...


class BusClosed(Exception):
    """The bus was closed while a request waited for it."""


@dataclass
class SyncReadResult:
    """What a SYNC_READ brought back: data from every servo that answered."""

    data: dict[int, bytes] = field(default_factory=dict)
    errors: dict[int, int] = field(default_factory=dict)  # status error byte, when non-zero
    missing: list[int] = field(default_factory=list)


@dataclass
class BusStats:
    """Counters for every kind of failure, for /metrics and the fault tests.

    ``garbled`` and ``stray_bytes`` count bytes thrown away (the same however the
    line chunked them); ``timeout`` and ``truncated`` count servos that gave no
    valid reply; every other kind counts packets or retries.
    """

    transactions: Counter[str] = field(default_factory=Counter)
    failures: Counter[str] = field(default_factory=Counter)
    bytes_out: int = 0
    bytes_in: int = 0

    def fail(self, kind: str, n: int = 1) -> None:
        self.failures[kind] += n


@dataclass(order=True)
class _Request:
    priority: int
    seq: int
    packet: bytes = field(compare=False)
    expect: tuple[int, ...] = field(compare=False)  # ids whose status we wait for
    length: int = field(compare=False)  # param bytes expected in each status
    kind: str = field(compare=False)
    future: asyncio.Future[dict[int, Packet]] = field(compare=False)


class ServoBus:
    """Request/response over a ByteLink, serialised through one owner task."""

    def __init__(self, link: ByteLink, *, reply_margin_s: float = 0.006, retries: int = 1) -> None:
        self.link = link
        self.margin = reply_margin_s
        self.retries = retries
        self.stats = BusStats()
        # Return delay of the servos (register 7, 2 µs units); the default is 0.
        self.return_delay_s = 0.0
        self._rx = bytearray()
        self._rx_wakeup: asyncio.Future[None] | None = None
        self._queue: asyncio.PriorityQueue[_Request] = asyncio.PriorityQueue()
        self._seq = itertools.count()
        self._owner: asyncio.Task[None] | None = None
        self._closed = False
        self._suspect = False  # replies of an earlier exchange may still be on the way
        self._throttled = Throttled(log)
        link.set_receiver(self._on_bytes)

    # -- lifecycle ---------------------------------------------------------

    def start(self) -> None:
        if self._owner is None:
            self._owner = asyncio.get_running_loop().create_task(self._run(), name="bus-owner")

    async def close(self) -> None:
        self._closed = True
        if self._owner is not None:
            self._owner.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._owner
            self._owner = None
        while not self._queue.empty():
            req = self._queue.get_nowait()
            if not req.future.done():
                req.future.set_exception(BusClosed("bus closed"))
        await self.link.close()

    # -- public requests -----------------------------------------------------

    async def ping(self, servo_id: int, *, priority: int = PRIORITY_SERVICE) -> bool:
        got = await self._request(protocol.ping(servo_id), (servo_id,), 0, "ping", priority)
        return servo_id in got

    async def read(
        self, servo_id: int, address: int, length: int, *, priority: int = PRIORITY_SERVICE
    ) -> bytes | None:
        """Read ``length`` bytes from one servo; None when no valid reply came."""
        pkt = protocol.read(servo_id, address, length)
        got = await self._request(pkt, (servo_id,), length, "read", priority)
        reply = got.get(servo_id)
        return reply.params if reply is not None else None

    async def write(
        self, servo_id: int, address: int, data: bytes, *, priority: int = PRIORITY_SERVICE
    ) -> bool:
        """Write and wait for the servo's acknowledgement."""
        pkt = protocol.write(servo_id, address, data)
        got = await self._request(pkt, (servo_id,), 0, "write", priority)
        return servo_id in got

    async def sync_read(
        self,
        ids: Sequence[int],
        address: int,
        length: int,
        *,
        priority: int = PRIORITY_CONTROL,
        retries: int = 0,
    ) -> SyncReadResult:
        """One SYNC_READ; each servo answers with its own status packet."""
        pkt = protocol.sync_read(address, length, ids)

        # A retry asks only the servos still missing: re-asking all of them would
        # put replies nobody waits for on the wire (counted as unexpected ids) and
        # outrun a deadline sized for the missing ones.
        def again(pending: Sequence[int]) -> bytes:
            return protocol.sync_read(address, length, pending)

        got = await self._request(
            pkt, tuple(ids), length, "sync_read", priority, retries, rebuild=again
        )
        result = SyncReadResult()
        for sid in ids:
            reply = got.get(sid)
            if reply is None:
                result.missing.append(sid)
                continue
            result.data[sid] = reply.params
            if reply.code:
                result.errors[sid] = reply.code
        return result

    async def sync_write(
        self,
        address: int,
        length: int,
        data_by_id: Mapping[int, bytes],
        *,
        priority: int = PRIORITY_CONTROL,
    ) -> None:
        """One SYNC_WRITE (broadcast, no reply)."""
        if not data_by_id:
            return
        pkt = protocol.sync_write(address, length, data_by_id)
        await self._request(pkt, (), 0, "sync_write", priority, 0)

    # -- the owner task --------------------------------------------------------

    async def _request(
        self,
        packet: bytes,
        expect: tuple[int, ...],
        length: int,
        kind: str,
        priority: int,
        retries: int | None = None,
        *,
        rebuild: Callable[[Sequence[int]], bytes] | None = None,
    ) -> dict[int, Packet]:
        if self._closed:
            raise BusClosed("bus closed")
        if self._owner is None:
            self.start()
        tries = 1 + (self.retries if retries is None else retries)
        got: dict[int, Packet] = {}
        for attempt in range(tries):
            fut: asyncio.Future[dict[int, Packet]] = asyncio.get_running_loop().create_future()
            pending = tuple(i for i in expect if i not in got)
            if attempt and rebuild is not None:
                packet = rebuild(pending)
            self._queue.put_nowait(
                _Request(priority, next(self._seq), packet, pending, length, kind, fut)
            )
            got.update(await fut)
            if all(i in got for i in expect):
                break
            if attempt + 1 < tries:
                self.stats.fail("retry")
        return got

    async def _run(self) -> None:
        while True:
            req = await self._queue.get()
            if req.future.done():  # the caller was cancelled
                continue
            try:
                result = await self._transact(req)
            except asyncio.CancelledError:
                if not req.future.done():
                    req.future.set_exception(BusClosed("bus closed"))
                raise
            except Exception as exc:  # a broken link must not kill the owner silently
                self._throttled.exception("link", "bus transaction failed", time.monotonic())
                self.stats.fail("link")
                if not req.future.done():
                    req.future.set_exception(exc)
                continue
            if not req.future.done():
                req.future.set_result(result)

    def wire_time(self, n_bytes: int) -> float:
        return n_bytes * BITS_PER_BYTE / self.link.baud

    async def _transact(self, req: _Request) -> dict[int, Packet]:
        loop = asyncio.get_running_loop()
        if self._rx:
            # Late bytes of an earlier exchange: drop them so they are not taken for this one.
            self.stats.fail("stray_bytes", len(self._rx))
            self._rx.clear()
            self._suspect = True
        self.stats.transactions[req.kind] += 1
        self.stats.bytes_out += len(req.packet)
        self.link.write(req.packet)
        if not req.expect:
            # No reply: just let the packet leave the wire before the next one.
            await asyncio.sleep(self.wire_time(len(req.packet)))
            return {}
        reply_bytes = len(req.expect) * (STATUS_OVERHEAD + req.length)
        deadline = (
            loop.time()
            + self.wire_time(len(req.packet) + reply_bytes)
            + len(req.expect) * self.return_delay_s
            + self.margin
        )
        got: dict[int, Packet] = {}
        wanted = set(req.expect)
        # A status packet names no request. After a lost, late or stray reply, more
        # late ones may still come, ahead of ours: taking the first for our answer
        # would leave the bus one answer behind for good. So listen until the
        # deadline and let each servo's last reply (the line is FIFO) win.
        listen_out, self._suspect = self._suspect, False
        while True:
            self._parse(got, wanted, req)
            if wanted <= got.keys() and not listen_out:
                break
            remaining = deadline - loop.time()
            if remaining <= 0:
                break
            self._rx_wakeup = loop.create_future()
            handle = loop.call_later(remaining, _wake, self._rx_wakeup)
            try:
                await self._rx_wakeup
            finally:
                handle.cancel()
                self._rx_wakeup = None
        self._parse(got, wanted, req)
        missing = wanted - got.keys()
        if missing:
            self.stats.fail("truncated" if self._rx else "timeout", len(missing))
            self._suspect = True
        return got

    def _parse(self, got: dict[int, Packet], wanted: set[int], req: _Request) -> None:
        while self._rx:
            consumed, pkt = protocol.decode(self._rx)
            if pkt is None:
                if consumed:
                    self.stats.fail("garbled", consumed)
                    del self._rx[:consumed]
                    continue
                return
            del self._rx[:consumed]
            # decode() skips noise and corrupt or cut packets in front of a good one
            # silently: count those bytes too, or a corrupt reply reads as a mere timeout.
            skipped = consumed - (len(pkt.params) + STATUS_OVERHEAD)
            if skipped:
                self.stats.fail("garbled", skipped)
            if pkt.id not in wanted:
                self.stats.fail("unexpected_id")
                self._suspect = True
            elif len(pkt.params) != req.length:
                self.stats.fail("wrong_length")
                self._suspect = True
            else:
                if pkt.id in got:
                    self.stats.fail("duplicate")  # a late reply of an earlier exchange
                    self._suspect = True
                got[pkt.id] = pkt  # the last one wins: it is the fresh one
                if pkt.code:
                    self.stats.fail("servo_error")

    def _on_bytes(self, data: bytes) -> None:
        self.stats.bytes_in += len(data)
        self._rx += data
        if self._rx_wakeup is not None and not self._rx_wakeup.done():
            self._rx_wakeup.set_result(None)


def _wake(fut: asyncio.Future[None]) -> None:
    if not fut.done():
        fut.set_result(None)
