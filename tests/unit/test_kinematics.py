"""Base inverse kinematics and the common-factor speed limit."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from lupin.kinematics import differential, mecanum, scale_to_limit
from lupin.mux import Twist

R, TRACK, BASE = 0.05, 0.30, 0.20  # wheel radius, track width, wheelbase (m)
speed = st.floats(-2.0, 2.0, allow_nan=False)


def test_differential_straight_spin_and_ignored_strafe() -> None:
    assert differential(Twist(0.5), TRACK, R) == pytest.approx((10.0, 10.0))
    # Counter-clockwise: left wheel backward, right forward, at w * track/2 / r.
    assert differential(Twist(angular_z=1.0), TRACK, R) == pytest.approx((-3.0, 3.0))
    assert differential(Twist(0.5, 0.4, 0.0), TRACK, R) == differential(Twist(0.5), TRACK, R)


def test_mecanum_straight() -> None:
    assert mecanum(Twist(0.5), BASE, TRACK, R) == pytest.approx((10.0,) * 4)


def test_mecanum_strafe_left() -> None:
    fl, fr, rl, rr = mecanum(Twist(linear_y=0.5), BASE, TRACK, R)
    assert (fl, fr, rl, rr) == pytest.approx((-10.0, 10.0, 10.0, -10.0))


def test_mecanum_spin() -> None:
    k = (BASE / 2 + TRACK / 2) / R  # 5.0
    assert mecanum(Twist(angular_z=1.0), BASE, TRACK, R) == pytest.approx((-k, k, -k, k))


@given(speed, speed, speed)
def test_mecanum_round_trips_through_forward_kinematics(vx: float, vy: float, wz: float) -> None:
    fl, fr, rl, rr = mecanum(Twist(vx, vy, wz), BASE, TRACK, R)
    lsum = BASE / 2 + TRACK / 2
    assert R / 4 * (fl + fr + rl + rr) == pytest.approx(vx, abs=1e-9)
    assert R / 4 * (-fl + fr + rl - rr) == pytest.approx(vy, abs=1e-9)
    assert R / (4 * lsum) * (-fl + fr - rl + rr) == pytest.approx(wz, abs=1e-9)


def test_refuses_non_finite_twists_and_bad_geometry() -> None:
    with pytest.raises(ValueError, match="non-finite"):
        differential(Twist(math.nan), TRACK, R)
    with pytest.raises(ValueError, match="non-finite"):
        mecanum(Twist(0, 0, math.inf), BASE, TRACK, R)
    with pytest.raises(ValueError, match="wheel_radius_m"):
        differential(Twist(1.0), TRACK, 0.0)
    with pytest.raises(ValueError, match="wheelbase_m"):
        mecanum(Twist(1.0), -0.1, TRACK, R)


def test_scale_leaves_speeds_within_the_limit_alone() -> None:
    assert scale_to_limit([1.0, -4.0, 4.0], 4.0) == (1.0, -4.0, 4.0)
    assert scale_to_limit([], 4.0) == ()


def test_scale_scales_all_wheels_together() -> None:
    # A saturated turn: clipping each wheel would give (4, 4), a straight line.
    out = scale_to_limit([6.0, 8.0], 4.0)
    assert out == pytest.approx((3.0, 4.0))
    assert out[0] / out[1] == pytest.approx(6.0 / 8.0)
    out4 = scale_to_limit(mecanum(Twist(1.0, 0.5, 0.3), BASE, TRACK, R), 4.0)
    assert max(abs(s) for s in out4) == pytest.approx(4.0)


@given(st.lists(st.floats(-100, 100, allow_nan=False), min_size=1, max_size=4), st.floats(0.1, 50))
def test_scale_keeps_ratios_and_respects_the_limit(speeds: list[float], limit: float) -> None:
    out = scale_to_limit(speeds, limit)
    assert max(abs(s) for s in out) <= limit * (1 + 1e-12)
    peak = max(abs(s) for s in speeds)
    factor = 1.0 if peak <= limit else limit / peak
    assert out == pytest.approx(tuple(s * factor for s in speeds))
    assert all(math.copysign(1, a) == math.copysign(1, b) for a, b in zip(out, speeds, strict=True))


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_scale_refuses_non_finite_speeds(bad: float) -> None:
    with pytest.raises(ValueError, match="wheel speed 1 is not finite"):
        scale_to_limit([1.0, bad], 4.0)


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf])
def test_scale_refuses_a_bad_limit(bad: float) -> None:
    with pytest.raises(ValueError, match="max_speed"):
        scale_to_limit([1.0], bad)
