"""hidapi DS4 reader: raw DualShock 4 input reports -> PadFrame, parsed from a table.

The report layout is data (``DS4_REPORTS``, ``DS4_AXES``, ``DS4_BUTTONS``), not
code: USB input report 0x01 carries the pad state from byte 1; Bluetooth report
0x11 carries the same bytes from byte 3. The frame has the kernel hid-sony
order (the ``ds4`` mapping file is written against it), so the evdev and hid
paths to a DS4 share one mapping: stick-up reads -1, triggers rest at -1.

hidapi is blocking, so each read runs in a worker thread with a short timeout;
an I/O error yields ``None`` (a release) and the pad is re-opened when it returns.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import AsyncIterator, Callable
from concurrent.futures import Executor
from dataclasses import dataclass
from typing import Any

from lupin.pad import PadFrame

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ReportLayout:
    base: int  # byte offset of the left stick X, where the shared state block starts
    length: int  # shortest report that holds the whole state block
    transport: str


# Report id -> where the state block is. Offsets below are relative to ``base``.
DS4_REPORTS: dict[int, ReportLayout] = {
    0x01: ReportLayout(base=1, length=10, transport="usb"),
    0x11: ReportLayout(base=3, length=12, transport="bluetooth"),
}
STICK, TRIGGER = "stick", "trigger"
# (joy axis index, byte offset, kind): left X/Y, L2, right X/Y, R2 (hid-sony order).
DS4_AXES: tuple[tuple[int, int, str], ...] = (
    (0, 0, STICK),
    (1, 1, STICK),
    (2, 7, TRIGGER),
    (3, 2, STICK),
    (4, 3, STICK),
    (5, 8, TRIGGER),
)
HAT_OFFSET, HAT_AXES = 4, (6, 7)  # low nibble of byte 4; D-pad X and Y axes
# Hat value -> (x, y), up and left negative as the kernel reports them; 8 = released.
DS4_HAT = ((0, -1), (1, -1), (1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1))
# (joy button index, byte offset, bit mask).
DS4_BUTTONS: tuple[tuple[int, int, int], ...] = (
    (0, 4, 0x20),  # cross
    (1, 4, 0x40),  # circle
    (2, 4, 0x80),  # triangle
    (3, 4, 0x10),  # square
    (4, 5, 0x01),  # L1
    (5, 5, 0x02),  # R1
    (6, 5, 0x04),  # L2 (digital)
    (7, 5, 0x08),  # R2 (digital)
    (8, 5, 0x10),  # share
    (9, 5, 0x20),  # options
    (10, 6, 0x01),  # PS
    (11, 5, 0x40),  # L3
    (12, 5, 0x80),  # R3
)
DS4_VID, DS4_PIDS = 0x054C, (0x05C4, 0x09CC)
READ_SIZE, READ_TIMEOUT_MS = 128, 200


def parse_ds4_report(report: bytes, t: float) -> PadFrame | None:
    """One raw report -> a frame; None for a report id not in the table or too short."""
    if not report or report[0] not in DS4_REPORTS:
        return None
    layout = DS4_REPORTS[report[0]]
    if len(report) < layout.length:
        return None
    block = report[layout.base :]
    axes = [0.0] * 8
    for index, offset, kind in DS4_AXES:
        raw = block[offset]
        # Sticks centre at 127.5 of 0..255; triggers go 0 (rest) .. 255 (full) -> -1..1.
        axes[index] = (raw - 127.5) / 127.5 if kind == STICK else raw / 127.5 - 1.0
    hat = block[HAT_OFFSET] & 0x0F
    if hat < len(DS4_HAT):
        axes[HAT_AXES[0]], axes[HAT_AXES[1]] = map(float, DS4_HAT[hat])
    buttons = tuple(1 if block[offset] & mask else 0 for _, offset, mask in DS4_BUTTONS)
    return PadFrame(t, tuple(axes), buttons)


def parse_vid_pid(arg: str) -> tuple[int, int]:
    vid, sep, pid = arg.partition(":")
    try:
        if not sep:
            raise ValueError
        return int(vid, 16), int(pid, 16)
    except ValueError:
        raise ValueError(f"bad hid id {arg!r}: use hex VID:PID, e.g. 054c:05c4") from None


def _open_hid(vid: int, pid: int) -> Any:
    import hid  # lazily: a machine without hidapi loses only this reader

    device = hid.device()
    device.open(vid, pid)
    # Over Bluetooth a DS4 sends the short 0x01 report until feature 0x02 is read;
    # reading it switches the pad to the full 0x11 report.
    with contextlib.suppress(OSError, ValueError):
        device.get_feature_report(0x02, 37)
    return device


class HidReader:
    """A DS4-class pad through hidapi (``hid:VID:PID``)."""

    def __init__(
        self,
        arg: str | None,
        *,
        layout: str,
        grab: bool = False,
        poll_s: float = 0.5,
        open_device: Callable[[int, int], Any] = _open_hid,
        clock: Callable[[], float] = time.monotonic,
        executor: Executor | None = None,
    ) -> None:
        self.vid, self.pid = parse_vid_pid(arg or f"{DS4_VID:04x}:{DS4_PIDS[0]:04x}")
        self.layout = layout
        self.name = f"hid:{self.vid:04x}:{self.pid:04x}"
        self.transport = "hid"
        self.poll_s = poll_s
        self._open_device = open_device
        self._clock = clock
        self._executor = executor  # None: the loop's default thread pool
        self._device: Any = None
        self._pending: asyncio.Future[Any] | None = None
        self._closed = False
        self.ignored = 0  # reports not in the table (or short)
        if open_device is _open_hid:
            import hid  # noqa: F401  fail now (AdapterNotFound upstream), not on first read

    async def frames(self) -> AsyncIterator[PadFrame | None]:
        try:
            while not self._closed:
                device = await self._wait_for_device()
                last: tuple[tuple[float, ...], tuple[int, ...]] | None = None
                try:
                    while True:
                        data = await self._read(device)
                        if not data:
                            continue  # read timeout: nothing changed
                        frame = parse_ds4_report(bytes(data), self._clock())
                        if frame is None:
                            self.ignored += 1
                            continue
                        self.transport = DS4_REPORTS[data[0]].transport
                        # The pad streams reports at ~250 Hz whether or not anything moved.
                        if (frame.axes, frame.buttons) != last:
                            last = (frame.axes, frame.buttons)
                            yield frame
                except OSError as exc:
                    log.warning("pad %s vanished (%s); waiting for it to return", self.name, exc)
                self._close_device()
                yield None
        finally:
            self._close_device()

    async def close(self) -> None:
        self._closed = True
        self._close_device()

    async def _wait_for_device(self) -> Any:
        warned = False
        while True:
            try:
                self._device = self._open_device(self.vid, self.pid)
                log.info("pad opened: %s", self.name)
                return self._device
            except OSError as exc:
                if not warned:
                    log.warning("pad %s: cannot open yet (%s); polling", self.name, exc)
                    warned = True
            await asyncio.sleep(self.poll_s)

    async def _read(self, device: Any) -> list[int]:
        loop = asyncio.get_running_loop()
        self._pending = loop.run_in_executor(
            self._executor, device.read, READ_SIZE, READ_TIMEOUT_MS
        )
        # Shielded: a cancelled consumer must not let close() free the handle while
        # the worker thread is still inside hid_read().
        data: list[int] = await asyncio.shield(self._pending)
        return data

    def _close_device(self) -> None:
        device, self._device = self._device, None
        pending, self._pending = self._pending, None
        if device is None:
            return
        if pending is not None and not pending.done():
            pending.add_done_callback(lambda f: _close_quietly(device, f))
        else:
            _close_quietly(device, pending)


def _close_quietly(device: Any, done: asyncio.Future[Any] | None) -> None:
    if done is not None and not done.cancelled():
        done.exception()  # retrieved, so asyncio does not log it as never retrieved
    with contextlib.suppress(OSError):
        device.close()


__all__ = ["DS4_AXES", "DS4_BUTTONS", "DS4_REPORTS", "HidReader", "parse_ds4_report"]
