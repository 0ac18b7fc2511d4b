"""The state push: one task serialises the robot state once per frame for every client.

Why it is shaped like this: the control tick and the other clients must never
wait for a slow or stalled browser. So the broadcaster never awaits a client.
It drops the frame into each client's :class:`Outbox`, whose state slot holds
at most one frame (a newer one replaces an unsent one), and each client's own
writer task does the awaiting. A stalled client only ever costs one string.
"""

from __future__ import annotations

import asyncio
import logging
from collections import deque
from collections.abc import Callable

from pydantic import BaseModel

log = logging.getLogger(__name__)


class Outbox:
    """One client's pending frames: its replies in order, then the newest state.

    Replies are never dropped; instead, once ``max_replies`` are waiting, ``room``
    is cleared and the connection's reader waits on it before reading more: a
    client that does not read its replies stops being read (and its heartbeat
    then closes it), without costing the server memory.
    """

    def __init__(self, max_replies: int = 64) -> None:
        self.max_replies = max_replies
        self.state: str | None = None
        self.replies: deque[str] = deque()
        self.wake = asyncio.Event()
        self.room = asyncio.Event()
        self.room.set()
        self.replaced = 0  # states dropped unsent because a newer one came
        self.sent = 0

    def offer_state(self, frame: str) -> None:
        if self.state is not None:
            self.replaced += 1
        self.state = frame
        self.wake.set()

    def offer_reply(self, frame: str) -> None:
        self.replies.append(frame)
        if len(self.replies) >= self.max_replies:
            self.room.clear()
        self.wake.set()

    async def take(self) -> list[str]:
        """Wait for something to send; replies first, then the newest state."""
        await self.wake.wait()
        self.wake.clear()
        out = list(self.replies)
        self.replies.clear()
        self.room.set()
        if self.state is not None:
            out.append(self.state)
            self.state = None
        return out


def state_frame(state: BaseModel) -> str:
    """``{"type": "state", ...state}`` spliced into pydantic's JSON (no re-encode)."""
    body = state.model_dump_json()
    assert body.startswith("{") and body != "{}"
    return '{"type":"state",' + body[1:]


class StateBroadcaster:
    def __init__(self, snapshot: Callable[[], BaseModel], hz: float) -> None:
        self.snapshot = snapshot
        self.period = 1.0 / hz
        self.outboxes: set[Outbox] = set()
        self.frames = 0
        self._failing = False

    def publish(self) -> None:
        """Serialise once, offer to every client; never blocks, never raises."""
        if not self.outboxes:
            return
        try:
            frame = state_frame(self.snapshot())
        except Exception:
            if not self._failing:  # once per failure streak, not 20 times a second
                log.exception("cannot build the state frame; clients get none until it recovers")
            self._failing = True
            return
        if self._failing:
            log.info("state frames recovered")
            self._failing = False
        self.frames += 1
        for box in self.outboxes:
            box.offer_state(frame)

    async def run(self) -> None:
        loop = asyncio.get_running_loop()
        next_at = loop.time()
        while True:
            self.publish()
            next_at += self.period
            delay = next_at - loop.time()
            if delay < 0:  # fell behind: skip, do not burst to catch up
                next_at = loop.time()
                delay = 0
            await asyncio.sleep(delay)
