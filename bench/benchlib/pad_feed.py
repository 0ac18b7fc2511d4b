"""An in-memory pad reader: the benchmark hands frames over, the daemon's pad task reads them.

It satisfies :class:`lupin.pad.PadReader`, so the daemon's own pad task
(:func:`lupin.pad_task.run_pad`) consumes it exactly as it would an evdev pad.
:meth:`PadFeed.put` stamps the moment of hand-over with ``time.monotonic()``,
the clock the simulated servos stamp received packets with, so latency is
measured from the instant the pad "reports" a frame.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator

from lupin.pad import PadFrame

# Xbox over Bluetooth (config/pads/xbox-bluetooth.yaml): LB 6 is the dead-man,
# left stick forward is axis 1 (+1 forward), triggers (axes 4, 5) rest at +1.
BT_LB = 6
AXES, BUTTONS = 8, 15


class PadFeed:
    """A queue of frames as a pad reader."""

    name = "bench-feed"
    transport = "bench"

    def __init__(self) -> None:
        self._queue: asyncio.Queue[PadFrame | None] = asyncio.Queue()

    def put(self, *, lb: bool = False, fwd: float = 0.0) -> float:
        """Hand over one Bluetooth-layout frame; returns its ``time.monotonic()`` stamp."""
        axes = [0.0] * AXES
        axes[1], axes[4], axes[5] = fwd, 1.0, 1.0
        buttons = [0] * BUTTONS
        buttons[BT_LB] = int(lb)
        now = time.monotonic()
        self._queue.put_nowait(PadFrame(now, tuple(axes), tuple(buttons)))
        return now

    async def frames(self) -> AsyncIterator[PadFrame | None]:
        while True:
            yield await self._queue.get()

    async def close(self) -> None:
        return None
