"""The calibrator's pure parts: inputs from frames, and answers folded into a mapping."""

from __future__ import annotations

import math

from lupin.cli.pad_calibrate import STEPS, InputEdges, Press, Swing, apply_answers
from lupin.pad import PadFrame
from lupin.pad_mapping import load_mapping, parse_mapping


def fr(axes: tuple[float, ...], buttons: tuple[int, ...] = (0, 0, 0)) -> PadFrame:
    return PadFrame(0.0, axes, buttons)


def test_a_press_is_one_input_until_released() -> None:
    edges = InputEdges(fr((0.0,)))
    assert edges.feed(fr((0.0,), (0, 1, 0))) == [Press(1)]
    assert edges.feed(fr((0.0,), (0, 1, 0))) == []  # still held
    assert edges.feed(fr((0.0,), (0, 0, 0))) == []
    assert edges.feed(fr((0.0,), (0, 1, 0))) == [Press(1)]


def test_a_button_held_at_rest_is_not_an_input() -> None:
    edges = InputEdges(fr((0.0,), (1, 0, 0)))
    assert edges.feed(fr((0.0,), (1, 0, 0))) == []


def test_a_swing_reports_axis_direction_rest_and_extreme_on_return() -> None:
    edges = InputEdges(fr((0.0, 1.0)))  # axis 1 is a trigger resting at +1
    assert edges.feed(fr((-0.3, 1.0))) == []  # inside the start threshold
    assert edges.feed(fr((-0.7, 0.2))) == []
    assert edges.feed(fr((-1.0, -0.98))) == []
    out = edges.feed(fr((0.1, 0.9)))
    assert out == [Swing(0, -1, 0.0, -1.0), Swing(1, -1, 1.0, -0.98)]


def test_nan_axes_are_ignored() -> None:
    edges = InputEdges(fr((math.nan, 0.0)))
    assert edges.feed(fr((1.0, math.nan))) == []


def test_ds4_walk_has_no_deadman_step() -> None:
    assert "enable_button" not in [s.key for s in STEPS["ds4"]]
    assert next(s.key for s in STEPS["xbox-usb"]) == "enable_button"


def test_dpad_reported_as_buttons_becomes_a_button_control() -> None:
    base = load_mapping("xbox-usb").model_dump(mode="json", exclude_none=True)
    data = apply_answers(base, {"elbow": (Press(11), Press(12)), "linear_x": Swing(1, 1, 0, 1)})
    m = parse_mapping(data, "test")
    elbow = m.arm_controls["elbow"]
    assert (elbow.axis, elbow.plus_button, elbow.minus_button) == (None, 11, 12)
    # Pushing forward read +1, so the USB file's negated scale turns positive.
    assert (m.scale_linear.x, m.scale_linear_turbo.x) == (0.2, 0.6)
    assert m.scale_linear.y == -0.2  # not asked: left as it was
