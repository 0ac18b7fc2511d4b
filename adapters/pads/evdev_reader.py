"""evdev pad reader: kernel input events -> PadFrame in joy_node's index order.

The index order joy_node presented depends on the kernel driver, which depends
on the transport (runbook, "Xbox control layout"): xpad on a USB cable, the
shifted Microsoft-HID layout over Bluetooth (LB at 6, face buttons skipping 2),
hid-sony for a DS4. Each is a table below from evdev codes to joy indices, with
the sign joy_node gave each axis on that transport: the mapping files' scale
signs (positive on Bluetooth, negated on USB) are written against these.

Hot-plug: a read that fails (ENODEV on unplug) yields ``None`` (the teleop
counts it as a release), then the device is polled for every 0.5 s and
re-opened; a pad that returns never resumes motion by itself (the teleop needs
a fresh dead-man press).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import AsyncIterator, Callable, Mapping
from dataclasses import dataclass
from typing import Any

from lupin.pad import PadFrame
from lupin.pad_mapping import DEVICES_PATH, parse_input_devices

log = logging.getLogger(__name__)

# linux/input-event-codes.h, a stable kernel ABI; numbers here so that this module
# imports (and its tables can be read) without evdev installed.
EV_SYN, EV_KEY, EV_ABS = 0x00, 0x01, 0x03
SYN_REPORT, SYN_DROPPED = 0, 3
ABS_X, ABS_Y, ABS_Z, ABS_RX, ABS_RY, ABS_RZ = 0x00, 0x01, 0x02, 0x03, 0x04, 0x05
ABS_GAS, ABS_BRAKE, ABS_HAT0X, ABS_HAT0Y = 0x09, 0x0A, 0x10, 0x11
BTN_A, BTN_B, BTN_C, BTN_X, BTN_Y, BTN_Z = 0x130, 0x131, 0x132, 0x133, 0x134, 0x135
BTN_TL, BTN_TR, BTN_TL2, BTN_TR2 = 0x136, 0x137, 0x138, 0x139
BTN_SELECT, BTN_START, BTN_MODE, BTN_THUMBL, BTN_THUMBR = 0x13A, 0x13B, 0x13C, 0x13D, 0x13E
BTN_MISC = 0x100
TRANSPORTS = {0x03: "usb", 0x05: "bluetooth"}


@dataclass(frozen=True)
class EvdevLayout:
    """evdev code -> joy index. ``axes``: ABS code -> (index, negate); ``buttons``: KEY -> index."""

    axes: Mapping[int, tuple[int, bool]]
    buttons: Mapping[int, int]

    @property
    def n_axes(self) -> int:
        return max((i for i, _ in self.axes.values()), default=-1) + 1

    @property
    def n_buttons(self) -> int:
        return max(self.buttons.values(), default=-1) + 1


# xpad (USB cable): axes as the kernel reports them, so stick-forward reads -1.
XPAD = EvdevLayout(
    axes={
        ABS_X: (0, False),  # left stick X
        ABS_Y: (1, False),  # left stick Y
        ABS_Z: (2, False),  # LT
        ABS_RX: (3, False),  # right stick X
        ABS_RY: (4, False),  # right stick Y
        ABS_RZ: (5, False),  # RT
        ABS_HAT0X: (6, False),  # D-pad left/right
        ABS_HAT0Y: (7, False),  # D-pad up/down
    },
    buttons={
        BTN_A: 0, BTN_B: 1, BTN_X: 2, BTN_Y: 3, BTN_TL: 4, BTN_TR: 5,
        BTN_SELECT: 6, BTN_START: 7, BTN_MODE: 8, BTN_THUMBL: 9, BTN_THUMBR: 10,
    },
)  # fmt: skip

# Bluetooth (Microsoft HID): joy negated every axis, so stick-forward reads +1 and a
# trigger rests at +1 and reads -1 at full pull; buttons are BTN_A + index, which is
# why LB lands on 6 and the face buttons skip 2.
XBOX_BLUETOOTH = EvdevLayout(
    axes={
        ABS_X: (0, True),  # left stick X
        ABS_Y: (1, True),  # left stick Y
        ABS_Z: (2, True),  # right stick X
        ABS_RZ: (3, True),  # right stick Y
        ABS_GAS: (4, True),  # RT
        ABS_BRAKE: (5, True),  # LT
        ABS_HAT0X: (6, True),  # D-pad left/right
        ABS_HAT0Y: (7, True),  # D-pad up/down
    },
    buttons={code: code - BTN_A for code in range(BTN_A, BTN_THUMBR + 1)},
)

# hid-sony (DS4): cross, circle, triangle, square, L1, R1, L2, R2, share, options, PS, L3, R3.
HID_SONY = EvdevLayout(
    axes={
        ABS_X: (0, False), ABS_Y: (1, False), ABS_Z: (2, False),  # left X/Y, L2
        ABS_RX: (3, False), ABS_RY: (4, False), ABS_RZ: (5, False),  # right X/Y, R2
        ABS_HAT0X: (6, False), ABS_HAT0Y: (7, False),
    },
    buttons={
        BTN_A: 0, BTN_B: 1, BTN_X: 2, BTN_Y: 3, BTN_TL: 4, BTN_TR: 5, BTN_TL2: 6,
        BTN_TR2: 7, BTN_SELECT: 8, BTN_START: 9, BTN_MODE: 10, BTN_THUMBL: 11, BTN_THUMBR: 12,
    },
)  # fmt: skip

LAYOUT_TABLES: dict[str, EvdevLayout] = {
    "xbox-usb": XPAD,
    "xbox-bluetooth": XBOX_BLUETOOTH,
    "ds4": HID_SONY,
}


def generic_layout(abs_codes: list[int], key_codes: list[int]) -> EvdevLayout:
    """joydev's order for an unknown pad: supported codes in ascending order."""
    buttons = sorted(c for c in key_codes if c >= BTN_MISC)
    return EvdevLayout(
        axes={code: (i, False) for i, code in enumerate(sorted(abs_codes))},
        buttons={code: i for i, code in enumerate(buttons)},
    )


class EvdevTranslator:
    """Pure: fold evdev events into pad state; a SYN_REPORT closes a frame."""

    def __init__(
        self,
        layout: EvdevLayout,
        ranges: Mapping[int, tuple[int, int]],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.layout = layout
        self.ranges = dict(ranges)
        self.clock = clock
        self.axes = [0.0] * layout.n_axes
        self.buttons = [0] * layout.n_buttons
        self.dropped = False  # SYN_DROPPED seen: state is stale until a resync

    @classmethod
    def for_device(
        cls, device: Any, layout: EvdevLayout, clock: Callable[[], float] = time.monotonic
    ) -> EvdevTranslator:
        absinfo = dict(device.capabilities(absinfo=True).get(EV_ABS, []))
        t = cls(layout, {c: (i.min, i.max) for c, i in absinfo.items()}, clock)
        t.resync(device)
        return t

    def resync(self, device: Any) -> None:
        """Read the whole state back (after open, or after the kernel dropped events)."""
        for code, info in device.capabilities(absinfo=True).get(EV_ABS, []):
            self._set_axis(code, info.value)
        self.buttons = [0] * self.layout.n_buttons
        for code in device.active_keys():
            self._set_button(code, 1)
        self.dropped = False

    def feed(self, event: Any) -> PadFrame | None:
        """Apply one event; returns the frame when the event closes one (SYN_REPORT)."""
        if event.type == EV_SYN:
            if event.code == SYN_DROPPED:
                self.dropped = True
                return None
            if event.code == SYN_REPORT and not self.dropped:
                return self.snapshot()
            return None
        if self.dropped:
            return None  # the kernel says events were lost; wait for the resync
        if event.type == EV_ABS:
            self._set_axis(event.code, event.value)
        elif event.type == EV_KEY:
            self._set_button(event.code, event.value)  # 2 (autorepeat) is still held
        return None

    def snapshot(self) -> PadFrame:
        return PadFrame(self.clock(), tuple(self.axes), tuple(self.buttons))

    def _set_axis(self, code: int, raw: int) -> None:
        slot = self.layout.axes.get(code)
        if slot is None:
            return
        index, negate = slot
        lo, hi = self.ranges.get(code, (-1, 1))
        value = 0.0 if hi <= lo else 2.0 * (raw - lo) / (hi - lo) - 1.0
        value = max(-1.0, min(1.0, value))
        self.axes[index] = (-value if negate else value) + 0.0

    def _set_button(self, code: int, value: int) -> None:
        index = self.layout.buttons.get(code)
        if index is not None:
            self.buttons[index] = 1 if value else 0


def _is_gamepad(device: Any) -> bool:
    caps = device.capabilities(absinfo=False)
    return BTN_A in caps.get(EV_KEY, []) and ABS_X in caps.get(EV_ABS, [])


def _open_evdev(path: str) -> Any:
    import evdev  # lazily: a machine without evdev loses only this reader

    return evdev.InputDevice(path)


def _list_evdev() -> list[str]:
    """Candidate pads, in /proc/bus/input/devices order (the order layout detection used),
    so auto-pick never opens a keyboard; every event node if that file is unreadable."""
    try:
        text = DEVICES_PATH.read_text(encoding="utf-8", errors="replace")
    except OSError:
        import evdev

        return sorted(evdev.list_devices(), key=lambda p: (len(p), p))
    return [node for pad in parse_input_devices(text) if (node := pad.event_node) is not None]


class EvdevReader:
    """A pad on ``/dev/input/event*``: by path, or the first gamepad found (``arg`` None)."""

    def __init__(
        self,
        arg: str | None,
        *,
        layout: str,
        grab: bool = False,
        poll_s: float = 0.5,
        open_device: Callable[[str], Any] = _open_evdev,
        list_devices: Callable[[], list[str]] = _list_evdev,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.path = arg
        self.layout = layout
        self.grab = grab
        self.poll_s = poll_s
        self.name = arg or "evdev:auto"
        self.transport = "evdev"
        self._open_device = open_device
        self._list_devices = list_devices
        self._clock = clock
        self._device: Any = None
        self._closed = False
        self._warned: set[str] = set()
        if open_device is _open_evdev:
            import evdev  # noqa: F401  fail now (AdapterNotFound upstream), not on first read

    async def frames(self) -> AsyncIterator[PadFrame | None]:
        try:
            while not self._closed:
                device = await self._wait_for_device()
                try:
                    table = LAYOUT_TABLES.get(self.layout) or self._generic(device)
                    translator = EvdevTranslator.for_device(device, table, self._clock)
                    yield translator.snapshot()
                    while True:
                        for event in list(await device.async_read()):
                            frame = translator.feed(event)
                            if frame is not None:
                                yield frame
                        if translator.dropped:
                            translator.resync(device)
                            yield translator.snapshot()
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
        while True:
            device = self._try_open()
            if device is not None:
                self.name = str(getattr(device, "name", self.name))
                self.transport = TRANSPORTS.get(getattr(device.info, "bustype", -1), "evdev")
                log.info("pad opened: %s (%s, layout %s)", self.name, self.transport, self.layout)
                return device
            await asyncio.sleep(self.poll_s)

    def _try_open(self) -> Any:
        paths = [self.path] if self.path else self._list_devices()
        for path in paths:
            try:
                device = self._open_device(path)
            except OSError as exc:
                # Say it once per path and kind (EACCES: the user is not in `input`).
                key = f"{path}:{exc.errno}"
                if key not in self._warned:
                    self._warned.add(key)
                    log.warning("pad %s: cannot open (%s); polling", path, exc)
                continue
            if self.path or _is_gamepad(device):
                self._grab(device)
                self._device = device
                return device
            device.close()
        return None

    def _grab(self, device: Any) -> None:
        if not self.grab:
            return
        try:
            device.grab()  # exclusive: a running daemon sees nothing while we probe
        except OSError as exc:
            log.warning("could not grab %s (%s): a running daemon may react", self.name, exc)

    @staticmethod
    def _generic(device: Any) -> EvdevLayout:
        caps = device.capabilities(absinfo=False)
        return generic_layout(list(caps.get(EV_ABS, [])), list(caps.get(EV_KEY, [])))

    def _close_device(self) -> None:
        device, self._device = self._device, None
        if device is not None:
            with contextlib.suppress(OSError):
                device.close()


__all__ = ["LAYOUT_TABLES", "EvdevLayout", "EvdevReader", "EvdevTranslator", "generic_layout"]
