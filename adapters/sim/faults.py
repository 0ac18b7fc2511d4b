"""Fault injection for the simulated bus: what a bad cable, a noisy line or a slow servo does.

A fault applies to servos' replies (status packets), never to the instruction
the servo received: the servo still acts on a WRITE whose reply was dropped,
exactly as on a real bus, which is what makes retries interesting.

Kinds:

``drop``      the reply never arrives.
``corrupt``   one byte after the header is changed, so the checksum fails.
``truncate``  the reply is cut short (at least its first byte survives).
``delay``     the reply arrives ``seconds`` late (only a timed transport, the
              pty server, honours this; ``SimulatedBus.handle`` cannot wait).
``garbage``   1..8 random bytes arrive just before the reply. They never
              contain 0xFF, so they cannot fake a header and swallow the reply.

Each fault fires with probability ``rate`` per reply from a matching servo
(``ids=None`` matches all), at most ``count`` times if given. Every random
choice comes from the bus's seedable ``random.Random``, so a failing test
replays exactly.
"""

from __future__ import annotations

import random
from collections.abc import Iterable
from dataclasses import dataclass
from typing import NamedTuple

KINDS = ("drop", "corrupt", "truncate", "delay", "garbage")


class Reply(NamedTuple):
    """Bytes a servo puts on the wire, and how late (beyond its normal timing)."""

    id: int  # the servo answering
    data: bytes
    delay: float = 0.0


@dataclass
class Fault:
    kind: str
    ids: frozenset[int] | None = None
    rate: float = 1.0
    count: int | None = None  # remaining firings; None = unlimited
    seconds: float = 0.0
    fired: int = 0

    def matches(self, servo_id: int) -> bool:
        return (self.ids is None or servo_id in self.ids) and self.count != 0


def make_fault(
    kind: str,
    *,
    ids: Iterable[int] | None = None,
    rate: float = 1.0,
    count: int | None = None,
    seconds: float | None = None,
) -> Fault:
    if kind not in KINDS:
        raise ValueError(f"unknown fault kind {kind!r}; expected one of {', '.join(KINDS)}")
    if not 0.0 <= rate <= 1.0:
        raise ValueError(f"rate must be within 0..1, got {rate}")
    if count is not None and count < 0:
        raise ValueError(f"count must be >= 0, got {count}")
    if kind == "delay" and (seconds is None or seconds < 0):
        raise ValueError("a delay fault needs seconds >= 0")
    return Fault(
        kind,
        None if ids is None else frozenset(ids),
        rate,
        count,
        seconds or 0.0,
    )


def apply_faults(faults: list[Fault], reply: Reply, rng: random.Random) -> Reply | None:
    """The reply as the client will see it, or None if it was dropped."""
    servo_id, data, delay = reply
    for fault in faults:
        if not fault.matches(servo_id) or rng.random() >= fault.rate:
            continue
        fault.fired += 1
        if fault.count is not None:
            fault.count -= 1
        if fault.kind == "drop":
            return None
        if fault.kind == "corrupt":
            # Past FF FF ID LEN: changing LEN would make the reader wait for a
            # length that never comes; any later byte just breaks the checksum.
            at = rng.randrange(4, len(data))
            new = rng.choice([b for b in range(0xFF) if b != data[at]])
            data = data[:at] + bytes((new,)) + data[at + 1 :]
        elif fault.kind == "truncate":
            data = data[: rng.randrange(1, len(data))]
        elif fault.kind == "delay":
            delay += fault.seconds
        elif fault.kind == "garbage":
            data = bytes(rng.randrange(0xFF) for _ in range(rng.randint(1, 8))) + data
    return Reply(servo_id, data, delay)
