"""The pad task: frames in, twists to the mux and steps to the arm commander out.

One asyncio task per pad. A pump task moves the reader's frames into a queue;
the loop wakes on a frame or on the next timer deadline (the 20 Hz autorepeat
while the dead-man is engaged, the 10 Hz arm step while an arm control is
held) and otherwise sleeps: no polling while the pad is idle. A burst of frames
is coalesced (the latest wins) but a vanish is never coalesced away.

A reader that raises is logged and treated as a vanished pad (one zero, then
silence), then re-opened through the factory with exponential backoff. A reader
whose frames end (a finished replay) counts as vanished, and the task returns.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

from lupin.arm import ArmCommander
from lupin.mux import Twist
from lupin.pad import PadFrame, PadReader, coalesce
from lupin.teleop import AXIS_EPS, ArmTeleop, BaseTeleop, Publish

log = logging.getLogger(__name__)

BAD_AXES_LOG_S = 5.0  # a pad that keeps sending bad axes is reported at most this often


@dataclass
class PadStatus:
    """The pad's state for the API; the task updates it in place."""

    layout: str = ""
    reader: str = ""
    transport: str = ""
    source: str = ""
    connected: bool = False
    deadman_held: bool = False
    driving: bool = False
    last_frame_at: float | None = None  # clock() time of the last frame
    bad_axes: int = 0
    arm_refusals: int = 0
    reader_errors: int = 0

    def as_dict(self, now: float) -> dict[str, Any]:
        out = asdict(self)
        age = None if self.last_frame_at is None else max(0.0, now - self.last_frame_at)
        out["last_frame_age"] = age
        return out


class _PadLoop:
    def __init__(
        self,
        base: BaseTeleop,
        arm_teleop: ArmTeleop | None,
        submit_twist: Callable[[str, Twist], None],
        arm: ArmCommander | None,
        clock: Callable[[], float],
        status: PadStatus,
        on_state: Callable[[dict[str, Any]], None] | None,
    ) -> None:
        self.base = base
        self.arm_teleop = arm_teleop if arm is not None else None
        self.submit_twist = submit_twist
        self.arm = arm
        self.clock = clock
        self.status = status
        self.on_state = on_state
        self._next_arm: float | None = None
        self.frames_seen = 0
        self.bad_frames = 0  # frames with a NaN, infinite or out-of-range axis
        self._bad_logged = -math.inf
        self._edges: tuple[bool, bool, bool] = (False, False, False)
        status.source = base.source

    # -- one reader's lifetime --------------------------------------------------------

    async def consume(self, reader: PadReader) -> None:
        """Run until the reader's frames end; re-raise whatever the reader raised."""
        self.status.reader, self.status.transport = reader.name, reader.transport
        queue: deque[PadFrame | None] = deque()
        wake = asyncio.Event()

        async def pump() -> None:
            try:
                async for item in reader.frames():
                    queue.append(item)
                    wake.set()
            finally:
                wake.set()

        pump_task = asyncio.create_task(pump(), name="pad-pump")
        try:
            while True:
                deadline = self._deadline()
                timeout = None if deadline is None else max(0.0, deadline - self.clock())
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(wake.wait(), timeout)
                wake.clear()
                now = self.clock()
                items = coalesce(list(queue))
                queue.clear()
                for item in items:
                    self.handle(item, now)
                self.timers(now)
                if pump_task.done() and not queue:
                    pump_task.result()  # re-raises a reader fault
                    return
        finally:
            pump_task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await pump_task

    # -- events -----------------------------------------------------------------------

    def handle(self, item: PadFrame | None, now: float) -> None:
        if item is not None:
            self._check_axes(item, now)
        self._publish(self.base.update(item, now))
        if self.arm_teleop is not None:
            self.arm_teleop.on_frame(item)
        self.status.connected = item is not None
        if item is not None:
            self.frames_seen += 1
            self.status.last_frame_at = now
        self._report()

    def _check_axes(self, frame: PadFrame, now: float) -> None:
        """Warn (at most every BAD_AXES_LOG_S) about axes that are NaN, infinite or past
        ±1. The teleop reads them as neutral, so nothing moves; but a pad that reports
        them is broken, and until the reliability suite it did so without a word."""
        bad = [
            (i, v)
            for i, v in enumerate(frame.axes)
            if not math.isfinite(v) or abs(v) > 1 + AXIS_EPS
        ]
        if not bad:
            return
        self.bad_frames += 1
        if now - self._bad_logged < BAD_AXES_LOG_S:
            return
        self._bad_logged = now
        shown = ", ".join(f"{i}={v!r}" for i, v in bad[:8]) + (", ..." if len(bad) > 8 else "")
        log.warning(
            "pad %s: axes %s are NaN, infinite or beyond ±1; read as neutral (%d such frames)",
            self.status.reader or "reader",
            shown,
            self.bad_frames,
        )

    def timers(self, now: float) -> None:
        due = self.base.next_due()
        if due is not None and now >= due - 1e-6:
            self._publish(self.base.tick(now))
        at = self.arm_teleop
        if at is None or self.arm is None or not at.wants_tick:
            self._next_arm = None
            return
        if self._next_arm is None:
            self._next_arm = now  # the first step of a press goes out at once
        if now >= self._next_arm - 1e-6:
            at.send(self.arm, now)
            # Keep the 10 Hz cadence, but never try to catch up a backlog of steps.
            self._next_arm = max(self._next_arm + at.duration, now)
            self.status.arm_refusals = at.refusals

    def _deadline(self) -> float | None:
        times = [t for t in (self.base.next_due(), self._next_arm) if t is not None]
        return min(times) if times else None

    def _publish(self, out: Publish | None) -> None:
        if out is None:
            return
        try:
            self.submit_twist(out.source, out.twist)
        except Exception:
            log.exception("pad teleop: the mux refused a %s twist", out.source)

    def _report(self) -> None:
        s = self.status
        s.deadman_held, s.driving, s.bad_axes = (
            self.base.deadman_held,
            self.base.engaged,
            self.base.bad_axes,
        )
        edges = (s.connected, s.deadman_held, s.driving)
        if edges != self._edges:
            if s.connected != self._edges[0]:
                # A pad that vanishes stops the base: the journal must say so.
                what = "connected" if s.connected else "gone (counts as released)"
                log.info("pad %s: %s", s.reader or "reader", what)
            self._edges = edges
            if self.on_state is not None:
                self.on_state(s.as_dict(self.clock()))


async def run_pad(
    open_reader: Callable[[], PadReader],
    base_teleop: BaseTeleop,
    arm_teleop: ArmTeleop | None,
    *,
    submit_twist: Callable[[str, Twist], None],
    arm: ArmCommander | None,
    clock: Callable[[], float],
    status: PadStatus | None = None,
    on_state: Callable[[dict[str, Any]], None] | None = None,
    backoff: tuple[float, float] = (0.5, 5.0),
) -> None:
    """Drive the base and the arm from a pad until cancelled (or its frames end).

    ``open_reader`` is called for the first reader and again after a reader
    fault, with exponential backoff from ``backoff[0]`` to ``backoff[1]`` seconds.
    ``submit_twist(source, twist)`` feeds the mux; ``arm`` receives the arm
    steps through ``ArmCommander.move``. ``status`` is updated in place for the
    API and ``on_state`` is called with ``status.as_dict()`` on every change of
    connected / dead-man held / driving.
    """
    loop = _PadLoop(
        base_teleop, arm_teleop, submit_twist, arm, clock, status or PadStatus(), on_state
    )
    delay = backoff[0]
    last_error: str | None = None
    try:
        while True:
            reader: PadReader | None = None
            seen_before = loop.frames_seen
            try:
                reader = open_reader()
                await loop.consume(reader)
                log.info("pad %s: no more frames", reader.name)
                return
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                loop.status.reader_errors += 1
                # A new kind of failure is a warning (with its traceback the first time);
                # the same one again, every backoff period, is only debug noise.
                level = logging.DEBUG if str(exc) == last_error else logging.WARNING
                first, last_error = last_error is None, str(exc)
                log.log(
                    level, "pad reader failed (%s); retrying in %.1fs", exc, delay, exc_info=first
                )
                # A faulted reader is a vanished pad: one zero if driving, then silence.
                loop.handle(None, clock())
            finally:
                if reader is not None:
                    with contextlib.suppress(Exception):
                        await reader.close()
            if loop.frames_seen > seen_before:
                delay = backoff[0]  # it worked for a while: start the backoff afresh
            await asyncio.sleep(delay)
            delay = min(delay * 2, backoff[1])
    finally:
        # Cancelled or finished: whatever the pad was doing counts as a release.
        loop.handle(None, clock())


__all__ = ["PadStatus", "run_pad"]
