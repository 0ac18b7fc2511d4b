"""hidapi DS4 reader: report parsing from recorded report bytes, and hot-plug."""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import errno
from collections.abc import Callable
from typing import Any

import pytest

from lupin.mux import Twist
from lupin.pad import PadFrame
from lupin.pad_mapping import load_mapping
from lupin.teleop import BaseTeleop, Publish
from lupin_adapters.pads.hid_reader import HidReader, parse_ds4_report

# DS4 v2 (054c:09cc) on USB, input report 0x01, 64 bytes, captured at rest:
# sticks centred (0x80), hat 8 (released), no buttons, triggers 0; bytes 10.. are
# timestamp, battery, IMU and touch data the teleop does not use.
USB_REST = bytes.fromhex(
    "0180807f7e0800a40000"
    "9c7a0bfeff0300f5ff0e00b3f3b62000"
    "00000000001b000001f18e815d2f0080"
    "00000080000000008000000080000000"
    "000000000000"
)
assert len(USB_REST) == 64


def usb_report(
    *,
    lx: int = 0x80,
    ly: int = 0x80,
    rx: int = 0x7F,
    ry: int = 0x7E,
    hat: int = 8,
    face: int = 0,
    b1: int = 0,
    b2: int = 0xA4,  # PS bit clear, counter bits set (must not read as PS/touch)
    l2: int = 0,
    r2: int = 0,
) -> bytes:
    head = bytes([0x01, lx, ly, rx, ry, (face & 0xF0) | hat, b1, b2, l2, r2])
    return head + USB_REST[10:]


def bt_report(usb: bytes) -> bytes:
    """The same state as Bluetooth report 0x11: two more header bytes, 78 bytes long."""
    return (bytes([0x11, 0xC0, 0x00]) + usb[1:] + bytes(78))[:78]


def test_usb_report_at_rest() -> None:
    frame = parse_ds4_report(USB_REST, 1.0)
    assert frame is not None
    assert frame.t == 1.0
    assert all(abs(a) < 0.02 for a in frame.axes[:2] + frame.axes[3:5])  # sticks centred
    assert frame.axes[2] == frame.axes[5] == -1.0  # triggers rest at -1
    assert frame.axes[6:] == (0.0, 0.0)  # hat released
    assert frame.buttons == (0,) * 13


def test_buttons_hat_sticks_and_triggers() -> None:
    # cross + triangle, hat up-left, L1 + options + R3, PS, L2 half, R2 full.
    raw = usb_report(face=0x20 | 0x80, hat=7, b1=0x01 | 0x20 | 0x80, b2=0xA5, l2=0x80, r2=0xFF,
                     lx=0x00, ly=0x00, rx=0xFF)  # fmt: skip
    frame = parse_ds4_report(raw, 0.0)
    assert frame is not None
    pressed = {i for i, b in enumerate(frame.buttons) if b}
    assert pressed == {0, 2, 4, 9, 10, 12}  # cross, triangle, L1, options, PS, R3
    assert frame.axes[0] == frame.axes[1] == -1.0  # stick up-left reads -1, -1
    assert frame.axes[3] == 1.0
    assert frame.axes[2] == pytest.approx(0.0, abs=0.01) and frame.axes[5] == 1.0
    assert frame.axes[6:] == (-1.0, -1.0)  # hat up-left


@pytest.mark.parametrize(("hat", "xy"), [(0, (0, -1)), (2, (1, 0)), (4, (0, 1)), (6, (-1, 0))])
def test_hat_directions(hat: int, xy: tuple[int, int]) -> None:
    frame = parse_ds4_report(usb_report(hat=hat), 0.0)
    assert frame is not None and frame.axes[6:] == xy


def test_bluetooth_report_parses_to_the_same_frame() -> None:
    usb = usb_report(face=0x40, hat=2, b1=0x02, r2=0xC0, ly=0x10)
    assert parse_ds4_report(bt_report(usb), 5.0) == parse_ds4_report(usb, 5.0)


def test_unknown_or_short_reports_are_ignored() -> None:
    assert parse_ds4_report(b"", 0.0) is None
    assert parse_ds4_report(bytes([0x05]) + USB_REST[1:], 0.0) is None
    assert parse_ds4_report(USB_REST[:9], 0.0) is None
    assert parse_ds4_report(bt_report(USB_REST)[:11], 0.0) is None


def test_ds4_stick_forward_drives_forward_on_manual() -> None:
    teleop = BaseTeleop(load_mapping("ds4"))
    rest = parse_ds4_report(USB_REST, 0.0)
    fwd = parse_ds4_report(usb_report(ly=0x00), 0.1)
    assert teleop.update(rest, 0.0) is None
    assert teleop.update(fwd, 0.1) == Publish("manual", Twist(0.2, 0.0, 0.0))


# -- the reader, against a fake hidapi device --------------------------------------------


class Inline(concurrent.futures.Executor):
    """Runs 'blocking' reads inline: no threads for the leak check to find."""

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Any:
        fut: concurrent.futures.Future[Any] = concurrent.futures.Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except Exception as exc:
            fut.set_exception(exc)
        return fut


class FakeHid:
    def __init__(self, reads: list[bytes | Exception]) -> None:
        self.reads = reads
        self.closed = False

    def read(self, size: int, timeout_ms: int) -> list[int]:
        if not self.reads:
            return []
        item = self.reads.pop(0)
        if isinstance(item, Exception):
            raise item
        return list(item)

    def close(self) -> None:
        self.closed = True


async def test_reader_dedups_reports_and_survives_unplug() -> None:
    pressed = usb_report(face=0x20)
    first = FakeHid([USB_REST, USB_REST, pressed, bytes([0x05, 1]), OSError(errno.EIO, "read")])
    second = FakeHid([bt_report(USB_REST)])
    opened: list[FakeHid] = []

    def open_device(vid: int, pid: int) -> FakeHid:
        assert (vid, pid) == (0x054C, 0x09CC)
        if len(opened) == 1 and not first.closed:
            raise AssertionError("re-opened before the old handle was closed")
        if len(opened) == 1 and not hasattr(open_device, "failed"):
            open_device.failed = True  # type: ignore[attr-defined]
            raise OSError("open failed")  # unplugged for one poll
        device = [first, second][len(opened)]
        opened.append(device)
        return device

    reader = HidReader(
        "054c:09cc", layout="ds4", poll_s=0.01, open_device=open_device, executor=Inline()
    )
    out: list[PadFrame | None] = []
    frames: Any = reader.frames()
    async with asyncio.timeout(3), contextlib.aclosing(frames):
        async for item in frames:
            out.append(item)
            if len(out) == 4:
                break
    await reader.close()
    assert [None if f is None else f.buttons[0] for f in out] == [0, 1, None, 0]
    assert reader.ignored == 1 and reader.transport == "bluetooth"
    assert first.closed and second.closed


def test_bad_vid_pid() -> None:
    with pytest.raises(ValueError, match="bad hid id"):
        HidReader("054c", layout="ds4", open_device=lambda v, p: None)
