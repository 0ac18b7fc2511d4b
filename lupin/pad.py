"""Pad frames, the reader interface, deadzone rescaling, burst coalescing, and ``open_pad``.

A pad reader (an adapter: evdev, hidapi, replay) turns whatever its device
speaks into :class:`PadFrame` snapshots in joy_node's index order, so the
mapping files and the teleop logic never see a transport. A reader yields
``None`` when the pad vanishes (unplug, Bluetooth drop) and keeps yielding
frames after it comes back: the teleop treats that ``None`` as a release.

The core never imports an adapter: :func:`open_pad` parses the ``--pad`` spec
and asks :mod:`lupin.registry` for the reader class by name.
"""

from __future__ import annotations

import math
from collections.abc import AsyncIterator, Iterable
from dataclasses import dataclass
from typing import Protocol

from lupin import registry

JOYSTICK_GROUP = "lupin.joystick"
# `--pad auto` is the evdev reader picking the first gamepad it finds.
AUTO_KIND = "evdev"


@dataclass(frozen=True, slots=True)
class PadFrame:
    """The whole pad at one instant: axes in -1..1 and buttons 0/1, joy_node order.

    ``t`` is the reader's monotonic time of the frame, in seconds.
    """

    t: float
    axes: tuple[float, ...]
    buttons: tuple[int, ...]

    def axis(self, index: int) -> float:
        """Axis ``index``, or NaN when the frame has no such axis (counted as bad)."""
        return self.axes[index] if 0 <= index < len(self.axes) else math.nan

    def button(self, index: int) -> bool:
        """Button ``index`` is down; an absent index (-1, or past the end) is up."""
        return 0 <= index < len(self.buttons) and self.buttons[index] != 0


class PadReader(Protocol):
    """What every pad adapter provides.

    ``frames()`` yields frames as the pad reports them, and ``None`` when the pad
    vanished; it keeps going after the pad returns. It ends only when the source
    is exhausted (a replay file) and raises only on a fault the reader cannot
    ride out (the pad task then reopens it with backoff).
    """

    name: str
    transport: str

    def frames(self) -> AsyncIterator[PadFrame | None]: ...

    async def close(self) -> None: ...


class PadReaderFactory(Protocol):
    """The object a ``lupin.joystick`` entry point names (usually the reader class).

    ``arg`` is the part of the ``--pad`` spec after ``kind:`` (None for ``auto``);
    ``layout`` picks the reader's code-to-index table; ``grab`` asks for exclusive
    access where the transport has it (the calibrator uses it so a running daemon
    sees nothing while buttons are probed).
    """

    def __call__(self, arg: str | None, *, layout: str, grab: bool = False) -> PadReader: ...


def apply_deadzone(value: float, deadzone: float) -> float:
    """joy_node's deadzone: 0 inside, then *rescaled* so full deflection still reads ±1.

    Clipping alone would make the first usable value jump from 0 to ``deadzone``
    and cap the stick short of full speed; rescaling keeps the response continuous.
    """
    if not 0.0 <= deadzone < 1.0:
        raise ValueError(f"deadzone must be in [0, 1), got {deadzone}")
    magnitude = abs(value)
    if magnitude <= deadzone:
        return 0.0
    scaled = min((magnitude - deadzone) / (1.0 - deadzone), 1.0)
    return math.copysign(scaled, value)


def coalesce(items: Iterable[PadFrame | None]) -> list[PadFrame | None]:
    """Collapse a burst: consecutive frames reduce to the latest one.

    A ``None`` (pad vanished) is a barrier and is never coalesced away, so a
    quick unplug/replug inside one burst still counts as a release.
    """
    out: list[PadFrame | None] = []
    for item in items:
        if out and item is not None and out[-1] is not None:
            out[-1] = item
        elif out and item is None and out[-1] is None:
            continue
        else:
            out.append(item)
    return out


def parse_pad_spec(spec: str) -> tuple[str, str | None] | None:
    """``--pad`` spec -> (adapter name, argument); None for ``none``."""
    if spec == "none":
        return None
    if spec == "auto":
        return AUTO_KIND, None
    kind, sep, arg = spec.partition(":")
    if not sep or not kind or not arg:
        raise ValueError(
            f"bad pad {spec!r}: use auto, none, evdev:DEVICE, hid:VID:PID or replay:FILE"
        )
    return kind, arg


def open_pad(spec: str, *, layout: str, grab: bool = False) -> PadReader | None:
    """Build the reader named by a ``--pad`` spec; None for ``none``.

    Construction does no device I/O (readers open, and re-open, inside
    ``frames()``), except that a replay file is parsed here so a bad line fails
    before anything moves. Raises ``registry.AdapterNotFound`` when the adapter
    or its library is missing, ``ValueError`` for a bad spec or file.
    """
    parsed = parse_pad_spec(spec)
    if parsed is None:
        return None
    kind, arg = parsed
    factory: PadReaderFactory = registry.load(JOYSTICK_GROUP, kind)
    return factory(arg, layout=layout, grab=grab)


__all__ = [
    "PadFrame",
    "PadReader",
    "PadReaderFactory",
    "apply_deadzone",
    "coalesce",
    "open_pad",
    "parse_pad_spec",
]
