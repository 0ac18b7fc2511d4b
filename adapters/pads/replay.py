"""Replay reader (``--pad replay:FILE``) and the recorder behind ``lupin pad-record``.

A replay file is JSON lines of raw frames as the pad reported them::

    {"t": 0.0, "axes": [0.0, 0.0, ...], "buttons": [0, 0, ...]}
    {"t": 1.5, "event": "disconnect"}
    {"t": 2.5, "event": "connect"}

``t`` is seconds from the moment the reader starts (the daemon is ready).
``disconnect`` yields ``None`` (the pad vanished); frames resume after
``connect``. Blank lines and ``#`` comments are skipped. The whole file is
checked when the reader is built, so a bad line is an error naming its line
number before anything is replayed; a replay never half-drives the robot.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from lupin.pad import PadFrame, PadReader

EVENTS = ("disconnect", "connect")


class ReplayError(ValueError):
    """A replay file is malformed; the message names the file and line."""


@dataclass(frozen=True, slots=True)
class ReplayEntry:
    t: float
    axes: tuple[float, ...] = ()
    buttons: tuple[int, ...] = ()
    event: str | None = None  # None for a frame


def _entry(obj: Any) -> ReplayEntry:
    if not isinstance(obj, dict):
        raise ValueError("expected a JSON object")
    t = obj.get("t")
    if isinstance(t, bool) or not isinstance(t, int | float) or not math.isfinite(t) or t < 0:
        raise ValueError(f"t must be a finite number of seconds >= 0, got {t!r}")
    if "event" in obj:
        if set(obj) != {"t", "event"} or obj["event"] not in EVENTS:
            raise ValueError(f"an event line is {{t, event}} with event one of {EVENTS}")
        return ReplayEntry(float(t), event=obj["event"])
    if set(obj) != {"t", "axes", "buttons"}:
        raise ValueError(f"a frame line has exactly t, axes, buttons; got {sorted(obj)}")
    axes, buttons = obj["axes"], obj["buttons"]
    # Axes may be NaN/inf (Python's JSON reads them): a replay can reproduce a bad pad.
    if not isinstance(axes, list) or not all(
        isinstance(a, int | float) and not isinstance(a, bool) for a in axes
    ):
        raise ValueError("axes must be a list of numbers")
    if not isinstance(buttons, list) or not all(
        isinstance(b, int) and not isinstance(b, bool) and b >= 0 for b in buttons
    ):
        raise ValueError("buttons must be a list of integers >= 0")
    return ReplayEntry(float(t), tuple(float(a) for a in axes), tuple(buttons))


def parse_replay(text: str, source: str) -> list[ReplayEntry]:
    """Check the whole file; raise ReplayError naming the first bad line."""
    entries: list[ReplayEntry] = []
    connected = True
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            entry = _entry(json.loads(line))
            if entries and entry.t < entries[-1].t:
                raise ValueError(f"t goes backwards ({entry.t} after {entries[-1].t})")
            if entry.event is None and not connected:
                raise ValueError("a frame while disconnected (add a connect line first)")
        except ValueError as exc:  # json.JSONDecodeError is a ValueError
            raise ReplayError(f"{source}:{number}: {exc}") from None
        if entry.event is not None:
            connected = entry.event == "connect"
        entries.append(entry)
    if not entries:
        raise ReplayError(f"{source}: no frames")
    return entries


class ReplayReader:
    """Plays a replay file in real time from the first ``frames()`` call."""

    def __init__(
        self,
        arg: str | None,
        *,
        layout: str,
        grab: bool = False,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not arg:
            raise ReplayError("replay needs a file: --pad replay:FILE")
        path = Path(arg)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise ReplayError(f"{path}: cannot read: {exc}") from None
        self.entries = parse_replay(text, str(path))
        self.layout = layout
        self.name = f"replay:{path.name}"
        self.transport = "replay"
        self._clock = clock

    async def frames(self) -> AsyncIterator[PadFrame | None]:
        start = self._clock()
        for entry in self.entries:
            delay = start + entry.t - self._clock()
            if delay > 0:
                await asyncio.sleep(delay)
            if entry.event == "disconnect":
                yield None
            elif entry.event is None:
                yield PadFrame(self._clock(), entry.axes, entry.buttons)

    async def close(self) -> None:
        return None

    @staticmethod
    async def record(reader: PadReader, path: Path | str, seconds: float | None = None) -> int:
        """``lupin pad-record`` reaches :func:`record` through the registry, by this name."""
        return await record(reader, path, seconds)


def _open_for_writing(path: Path | str) -> TextIO:
    # A local file opens without blocking the loop in any way that matters.
    return Path(path).open("w", encoding="utf-8")


async def record(
    reader: PadReader,
    path: Path | str,
    seconds: float | None = None,
    *,
    clock: Callable[[], float] = time.monotonic,
) -> int:
    """Write ``reader``'s frames to ``path`` as a replay file, for ``seconds`` (None: until
    cancelled). Lines are flushed as they come, so an interrupted recording keeps its
    frames. Returns the number of frames written."""
    count = 0
    start = clock()
    with _open_for_writing(path) as out:

        def write(obj: dict[str, Any]) -> None:
            out.write(json.dumps(obj) + "\n")
            out.flush()

        async def copy() -> None:
            nonlocal count
            gone = False
            async for item in reader.frames():
                t = round(clock() - start, 4)
                if item is None:
                    if not gone:
                        write({"t": t, "event": "disconnect"})
                    gone = True
                    continue
                if gone:
                    write({"t": t, "event": "connect"})
                    gone = False
                write({"t": t, "axes": list(item.axes), "buttons": list(item.buttons)})
                count += 1

        try:
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(seconds):
                    await copy()
        finally:
            await reader.close()
    return count


__all__ = ["ReplayEntry", "ReplayError", "ReplayReader", "parse_replay", "record"]
