"""evdev reader: real ``evdev.InputEvent`` objects through the per-transport tables."""

from __future__ import annotations

import asyncio
import contextlib
import errno
from collections.abc import Iterable
from types import SimpleNamespace
from typing import Any

import pytest

evdev = pytest.importorskip("evdev")
from evdev import AbsInfo, InputEvent  # noqa: E402
from evdev import ecodes as e  # noqa: E402

from lupin.mux import Twist  # noqa: E402
from lupin.pad import PadFrame  # noqa: E402
from lupin.pad_mapping import load_mapping  # noqa: E402
from lupin.teleop import BaseTeleop, Publish  # noqa: E402
from lupin_adapters.pads import evdev_reader as er  # noqa: E402

STICK = AbsInfo(value=0, min=-32768, max=32767, fuzz=16, flat=128, resolution=0)
XPAD_TRIGGER = AbsInfo(value=0, min=0, max=1023, fuzz=0, flat=0, resolution=0)
HAT = AbsInfo(value=0, min=-1, max=1, fuzz=0, flat=0, resolution=0)
# hid-microsoft over Bluetooth: unsigned stick and trigger ranges.
BT_STICK = AbsInfo(value=32768, min=0, max=65535, fuzz=255, flat=4095, resolution=0)
BT_TRIGGER = AbsInfo(value=0, min=0, max=1023, fuzz=3, flat=63, resolution=0)

XPAD_ABS = {
    e.ABS_X: STICK, e.ABS_Y: STICK, e.ABS_Z: XPAD_TRIGGER, e.ABS_RX: STICK,
    e.ABS_RY: STICK, e.ABS_RZ: XPAD_TRIGGER, e.ABS_HAT0X: HAT, e.ABS_HAT0Y: HAT,
}  # fmt: skip
XPAD_KEYS = [e.BTN_A, e.BTN_B, e.BTN_X, e.BTN_Y, e.BTN_TL, e.BTN_TR, e.BTN_SELECT, e.BTN_START,
             e.BTN_MODE, e.BTN_THUMBL, e.BTN_THUMBR]  # fmt: skip
BT_ABS = {
    e.ABS_X: BT_STICK, e.ABS_Y: BT_STICK, e.ABS_Z: BT_STICK, e.ABS_RZ: BT_STICK,
    e.ABS_GAS: BT_TRIGGER, e.ABS_BRAKE: BT_TRIGGER, e.ABS_HAT0X: HAT, e.ABS_HAT0Y: HAT,
}  # fmt: skip
BT_KEYS = list(range(e.BTN_A, e.BTN_THUMBR + 1))


class FakeDevice:
    """What the reader uses of ``evdev.InputDevice``: capabilities, keys, async reads."""

    def __init__(
        self,
        abs_info: dict[int, AbsInfo],
        keys: list[int],
        batches: Iterable[list[InputEvent] | Exception] = (),
        *,
        bustype: int = 0x03,
        name: str = "Microsoft X-Box One S pad",
        pressed: Iterable[int] = (),
    ) -> None:
        self.abs_info, self.keys, self.batches = abs_info, keys, list(batches)
        self.info = SimpleNamespace(bustype=bustype)
        self.name = name
        self.pressed = list(pressed)
        self.closed = self.grabbed = False

    def capabilities(self, absinfo: bool = True) -> dict[int, list[Any]]:
        axes = list(self.abs_info.items()) if absinfo else list(self.abs_info)
        return {e.EV_SYN: [0], e.EV_KEY: list(self.keys), e.EV_ABS: axes}

    def active_keys(self) -> list[int]:
        return self.pressed

    async def async_read(self) -> list[InputEvent]:
        if not self.batches:
            await asyncio.Event().wait()  # nothing more: block like a quiet pad
        batch = self.batches.pop(0)
        if isinstance(batch, Exception):
            raise batch
        return batch

    def grab(self) -> None:
        self.grabbed = True

    def close(self) -> None:
        self.closed = True


def ev(kind: int, code: int, value: int) -> InputEvent:
    return InputEvent(1700000000, 5000, kind, code, value)


SYN = (e.EV_SYN, e.SYN_REPORT, 0)


def events(*triples: tuple[int, int, int]) -> list[InputEvent]:
    return [ev(*t) for t in triples]


def test_codes_match_the_kernel_headers() -> None:
    for name in ("ABS_X", "ABS_Y", "ABS_Z", "ABS_RX", "ABS_RY", "ABS_RZ", "ABS_GAS",
                 "ABS_BRAKE", "ABS_HAT0X", "ABS_HAT0Y", "BTN_A", "BTN_B", "BTN_X", "BTN_Y",
                 "BTN_TL", "BTN_TR", "BTN_SELECT", "BTN_START", "BTN_THUMBR",
                 "EV_ABS", "EV_KEY", "SYN_DROPPED"):  # fmt: skip
        assert getattr(er, name) == getattr(e, name), name


def test_xpad_events_become_joy_indices() -> None:
    t = er.EvdevTranslator.for_device(FakeDevice(XPAD_ABS, XPAD_KEYS), er.XPAD, lambda: 1.0)
    assert t.feed(ev(e.EV_KEY, e.BTN_TL, 1)) is None  # nothing until SYN_REPORT
    assert t.feed(ev(e.EV_ABS, e.ABS_Y, -32768)) is None
    frame = t.feed(ev(*SYN))
    assert frame is not None
    assert frame.buttons[4] == 1  # LB is button 4 on USB
    assert frame.axes[1] == -1.0  # xpad reports stick-forward as -1
    for code, value in ((e.ABS_RX, 32767), (e.ABS_HAT0Y, -1), (e.ABS_RZ, 1023), (e.ABS_Z, 0)):
        t.feed(ev(e.EV_ABS, code, value))
    t.feed(ev(e.EV_KEY, e.BTN_X, 1))
    t.feed(ev(e.EV_KEY, e.BTN_START, 2))  # autorepeat value: still held
    frame = t.feed(ev(*SYN))
    assert frame is not None
    assert (frame.axes[3], frame.axes[7], frame.axes[5], frame.axes[2]) == (1.0, -1.0, 1.0, -1.0)
    assert (frame.buttons[2], frame.buttons[7]) == (1, 1)
    assert len(frame.axes) == 8 and len(frame.buttons) == 11


def test_bluetooth_events_take_the_shifted_layout_and_joy_signs() -> None:
    dev = FakeDevice(BT_ABS, BT_KEYS, bustype=0x05)
    t = er.EvdevTranslator.for_device(dev, er.XBOX_BLUETOOTH, lambda: 1.0)
    rest = t.snapshot()
    assert rest.axes[4] == rest.axes[5] == 1.0  # triggers rest at +1 on Bluetooth
    t.feed(ev(e.EV_KEY, e.BTN_TL, 1))
    t.feed(ev(e.EV_KEY, e.BTN_Y, 1))
    t.feed(ev(e.EV_ABS, e.ABS_Y, 0))  # stick fully forward
    t.feed(ev(e.EV_ABS, e.ABS_Z, 0))  # right stick fully left
    t.feed(ev(e.EV_ABS, e.ABS_GAS, 1023))  # RT fully pulled
    frame = t.feed(ev(*SYN))
    assert frame is not None
    assert (frame.buttons[6], frame.buttons[4]) == (1, 1)  # LB = 6, Y = 4
    assert (frame.axes[1], frame.axes[2], frame.axes[4]) == (1.0, 1.0, -1.0)


def test_initial_state_comes_from_the_device_not_zeros() -> None:
    abs_info = {**BT_ABS, e.ABS_BRAKE: BT_TRIGGER._replace(value=1023)}
    dev = FakeDevice(abs_info, BT_KEYS, bustype=0x05, pressed=[e.BTN_TL])
    frame = er.EvdevTranslator.for_device(dev, er.XBOX_BLUETOOTH, lambda: 0.0).snapshot()
    assert frame.axes[5] == -1.0 and frame.buttons[6] == 1


def test_syn_dropped_holds_frames_until_resync() -> None:
    dev = FakeDevice(XPAD_ABS, XPAD_KEYS)
    t = er.EvdevTranslator.for_device(dev, er.XPAD, lambda: 0.0)
    assert t.feed(ev(e.EV_SYN, e.SYN_DROPPED, 0)) is None
    t.feed(ev(e.EV_KEY, e.BTN_TL, 1))
    assert t.feed(ev(*SYN)) is None
    assert t.dropped
    dev.pressed = [e.BTN_TL]
    t.resync(dev)
    assert t.snapshot().buttons[4] == 1 and not t.dropped


def test_ds4_table_matches_the_hid_reader_order() -> None:
    t = er.EvdevTranslator.for_device(FakeDevice(XPAD_ABS, XPAD_KEYS), er.HID_SONY, lambda: 0.0)
    t.feed(ev(e.EV_KEY, e.BTN_SELECT, 1))  # share
    t.feed(ev(e.EV_KEY, e.BTN_THUMBR, 1))  # R3
    frame = t.feed(ev(*SYN))
    assert frame is not None and frame.buttons[8] == 1 and frame.buttons[12] == 1


def test_unknown_pad_gets_joydev_order() -> None:
    layout = er.generic_layout([e.ABS_HAT0X, e.ABS_X], [e.KEY_A, e.BTN_TR, e.BTN_A])
    assert layout.axes == {e.ABS_X: (0, False), e.ABS_HAT0X: (1, False)}
    assert layout.buttons == {e.BTN_A: 0, e.BTN_TR: 1}  # keyboard keys are not pad buttons


def test_same_push_same_twist_on_both_transports() -> None:
    """Kernel events -> table -> mapping file -> twist: the signs agree end to end."""
    results = []
    for layout, table, abs_info, keys, forward, lb in (
        ("xbox-usb", er.XPAD, XPAD_ABS, XPAD_KEYS, -32768, e.BTN_TL),
        ("xbox-bluetooth", er.XBOX_BLUETOOTH, BT_ABS, BT_KEYS, 0, e.BTN_TL),
    ):
        t = er.EvdevTranslator.for_device(FakeDevice(abs_info, keys), table, lambda: 0.0)
        teleop = BaseTeleop(load_mapping(layout))
        teleop.update(t.snapshot(), 0.0)
        t.feed(ev(e.EV_KEY, lb, 1))
        teleop.update(t.feed(ev(*SYN)), 0.1)
        t.feed(ev(e.EV_ABS, e.ABS_Y, forward))  # full forward, as the kernel reports it
        results.append(teleop.update(t.feed(ev(*SYN)), 0.2))
    assert results == [Publish("joy", Twist(0.2, 0.0, 0.0))] * 2


# -- the reader: open, hot-plug, auto-pick -----------------------------------------------------


async def take(reader: er.EvdevReader, n: int) -> list[PadFrame | None]:
    out: list[PadFrame | None] = []
    frames: Any = reader.frames()
    async with asyncio.timeout(3), contextlib.aclosing(frames):
        async for item in frames:
            out.append(item)
            if len(out) == n:
                break
    await reader.close()
    return out


async def test_unplug_yields_none_then_reopens_when_it_returns() -> None:
    gone = OSError(errno.ENODEV, "No such device")
    first = FakeDevice(XPAD_ABS, XPAD_KEYS, [events((e.EV_KEY, e.BTN_TL, 1), SYN), gone])
    second = FakeDevice(XPAD_ABS, XPAD_KEYS, pressed=[e.BTN_TL])
    attempts: list[str] = []

    def open_device(path: str) -> FakeDevice:
        attempts.append(path)
        if len(attempts) == 1:
            return first
        if len(attempts) < 4:
            raise FileNotFoundError(errno.ENOENT, "No such file", path)  # still unplugged
        return second

    reader = er.EvdevReader(
        "/dev/input/by-id/pad", layout="xbox-usb", poll_s=0.01, open_device=open_device
    )
    items = await take(reader, 4)
    assert items[0] is not None and items[0].buttons[4] == 0  # the initial state
    assert items[1] is not None and items[1].buttons[4] == 1
    assert items[2] is None  # vanished: the teleop counts it as a release
    assert items[3] is not None and items[3].buttons[4] == 1  # back, state read afresh
    assert first.closed and second.closed
    assert attempts == ["/dev/input/by-id/pad"] * 4
    assert reader.transport == "usb"


async def test_auto_picks_the_first_gamepad_and_grabs_it() -> None:
    keyboard = FakeDevice({}, [e.KEY_A, e.KEY_B], name="AT keyboard")
    pad = FakeDevice(BT_ABS, BT_KEYS, bustype=0x05, name="Xbox Wireless Controller")
    devices = {"/dev/input/event3": keyboard, "/dev/input/event21": pad}
    reader = er.EvdevReader(
        None,
        layout="xbox-bluetooth",
        grab=True,
        open_device=devices.__getitem__,
        list_devices=lambda: list(devices),
    )
    items = await take(reader, 1)
    assert keyboard.closed and pad.grabbed
    assert reader.name == "Xbox Wireless Controller" and reader.transport == "bluetooth"
    assert items[0] is not None and items[0].axes[4] == 1.0
