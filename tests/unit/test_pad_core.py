"""Pad core: deadzone rescaling, burst coalescing, the --pad spec and the registry factory."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from lupin import registry
from lupin.pad import PadFrame, apply_deadzone, coalesce, open_pad, parse_pad_spec


def test_deadzone_zero_inside_and_rescaled_outside() -> None:
    assert apply_deadzone(0.1, 0.15) == 0.0
    assert apply_deadzone(-0.15, 0.15) == 0.0
    assert apply_deadzone(0.575, 0.15) == pytest.approx(0.5)
    assert apply_deadzone(-0.575, 0.15) == pytest.approx(-0.5)
    assert apply_deadzone(1.0, 0.15) == 1.0  # clipping would stop at 0.85
    assert apply_deadzone(-1.0, 0.1) == -1.0
    assert apply_deadzone(0.3, 0.0) == 0.3
    with pytest.raises(ValueError, match="deadzone"):
        apply_deadzone(0.5, 1.0)


@given(st.floats(-1, 1), st.floats(-1, 1), st.floats(0, 0.9))
def test_deadzone_is_monotonic_continuous_and_bounded(a: float, b: float, dz: float) -> None:
    lo, hi = sorted((a, b))
    assert apply_deadzone(lo, dz) <= apply_deadzone(hi, dz)
    assert -1.0 <= apply_deadzone(a, dz) <= 1.0
    # Continuous at the edge: just outside the deadzone reads just above 0 (no jump).
    assert abs(apply_deadzone(math.copysign(dz + 1e-9, a), dz)) < 1e-6


def f(t: float) -> PadFrame:
    return PadFrame(t, (t,), (0,))


def test_coalesce_keeps_the_latest_frame_of_a_burst() -> None:
    assert coalesce([f(1), f(2), f(3)]) == [f(3)]
    assert coalesce([]) == []


def test_coalesce_never_drops_a_vanish() -> None:
    # An unplug/replug inside one burst must still be seen as a release.
    assert coalesce([f(1), f(2), None, f(3), f(4)]) == [f(2), None, f(4)]
    assert coalesce([None, None, f(1)]) == [None, f(1)]
    assert coalesce([f(1), None]) == [f(1), None]


def test_frame_accessors_tolerate_missing_indices() -> None:
    frame = PadFrame(0.0, (0.5,), (1,))
    assert frame.axis(0) == 0.5 and math.isnan(frame.axis(3)) and math.isnan(frame.axis(-1))
    assert frame.button(0) and not frame.button(5) and not frame.button(-1)


@pytest.mark.parametrize(
    ("spec", "parsed"),
    [
        ("none", None),
        ("auto", ("evdev", None)),
        ("evdev:/dev/input/event3", ("evdev", "/dev/input/event3")),
        ("hid:054c:05c4", ("hid", "054c:05c4")),
        ("replay:/tmp/a:b.jsonl", ("replay", "/tmp/a:b.jsonl")),
    ],
)
def test_parse_pad_spec(spec: str, parsed: tuple[str, str | None] | None) -> None:
    assert parse_pad_spec(spec) == parsed


def test_open_pad_asks_the_registry(tmp_path: Path) -> None:
    replay = tmp_path / "pad.jsonl"
    replay.write_text('{"t": 0, "axes": [0.0], "buttons": [0]}\n')
    reader = open_pad(f"replay:{replay}", layout="xbox-usb")
    assert reader is not None and reader.transport == "replay"
    assert open_pad("none", layout="xbox-usb") is None
    with pytest.raises(registry.AdapterNotFound, match=r"no lupin\.joystick adapter named 'bogus'"):
        open_pad("bogus:x", layout="xbox-usb")
    with pytest.raises(ValueError, match="bad pad"):
        open_pad("evdev:", layout="xbox-usb")


def test_every_builtin_reader_is_registered() -> None:
    assert {"evdev", "hid", "replay"} <= set(registry.available("lupin.joystick"))
