"""The base drive: twist to wheel goal speeds, and its own command timeout."""

from __future__ import annotations

import math

import pytest

from lupin.base import COUNTS_PER_RAD, BaseDrive
from lupin.config import load_profile
from lupin.mux import Twist


@pytest.fixture()
def diff(tmp_path: object) -> BaseDrive:
    profile = load_profile("so101", home=tmp_path)  # type: ignore[arg-type]
    assert profile.base is not None
    return BaseDrive(profile.base)


def test_forward_spins_mirrored_wheels_opposite_ways(diff: BaseDrive) -> None:
    diff.command(Twist(linear_x=0.1), stamp=0.0)
    goals = diff.wheel_goals(0.05)
    # 0.1 m/s on 0.05 m wheels = 2 rad/s; the right wheel is mounted mirrored.
    expected = round(2.0 * COUNTS_PER_RAD)
    assert goals == {7: expected, 9: -expected}


def test_command_timeout_stops_wheels(diff: BaseDrive) -> None:
    diff.command(Twist(linear_x=0.1), stamp=10.0)
    assert diff.wheel_goals(10.49)[7] != 0
    assert diff.wheel_goals(10.51) == {7: 0, 9: 0}


def test_none_from_mux_keeps_last_until_its_timeout(diff: BaseDrive) -> None:
    # The mux outputs nothing; the base still stops on its own timeout, counted
    # from when the source last published, not from the last tick.
    diff.command(Twist(angular_z=1.0), stamp=0.0)
    diff.command(None, stamp=0.4)
    assert diff.wheel_goals(0.45)[7] != 0
    assert diff.wheel_goals(0.55) == {7: 0, 9: 0}


def test_speed_limit_scales_both_wheels_together(diff: BaseDrive) -> None:
    diff.command(Twist(linear_x=1.0, angular_z=2.0), stamp=0.0)
    left, right = diff.wheel_speeds_rad_s(0.0)
    assert max(abs(left), abs(right)) == pytest.approx(4.0)
    # Unscaled: left = (1 - 0.2)/0.05 = 16, right = (1 + 0.2)/0.05 = 24; ratio kept.
    assert left / right == pytest.approx(16 / 24)


def test_stop_forgets_command(diff: BaseDrive) -> None:
    diff.command(Twist(linear_x=0.1), stamp=0.0)
    diff.stop()
    assert diff.wheel_goals(0.01) == {7: 0, 9: 0}


def test_mecanum_strafe(tmp_path: object) -> None:
    profile = load_profile("mecanum", home=tmp_path)  # type: ignore[arg-type]
    assert profile.base is not None
    base = BaseDrive(profile.base)
    base.command(Twist(linear_y=0.1), stamp=0.0)
    fl, fr, rl, rr = base.wheel_speeds_rad_s(0.0)
    assert math.copysign(1, fl) == -math.copysign(1, rl)
    assert fl == pytest.approx(-fr) and fl == pytest.approx(rr)
