"""Inverse kinematics of the base: a twist to wheel angular speeds, and the speed limit.

Conventions (ROS REP 103): ``linear_x`` m/s forward, ``linear_y`` m/s to the left,
``angular_z`` rad/s counter-clockwise seen from above. A positive wheel speed (rad/s)
rolls that wheel forward; per-wheel mounting direction (``invert``) is the caller's
business. Pure functions, no state.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from lupin.mux import Twist


def _check_twist(twist: Twist) -> None:
    if not twist.is_finite():
        raise ValueError(f"twist has a non-finite component: {twist}")


def _check_length(name: str, value: float) -> None:
    if not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive length in metres, got {value!r}")


def differential(twist: Twist, track_width_m: float, wheel_radius_m: float) -> tuple[float, float]:
    """(left, right) wheel speeds in rad/s for a two-wheel differential base.

    ``linear_y`` is ignored: a differential base cannot move sideways, and the
    mux's producers (the pad's strafe axis, the HMI) may still send it.
    """
    _check_twist(twist)
    _check_length("track_width_m", track_width_m)
    _check_length("wheel_radius_m", wheel_radius_m)
    half = track_width_m / 2.0
    left = (twist.linear_x - twist.angular_z * half) / wheel_radius_m
    right = (twist.linear_x + twist.angular_z * half) / wheel_radius_m
    return left, right


def mecanum(
    twist: Twist, wheelbase_m: float, track_width_m: float, wheel_radius_m: float
) -> tuple[float, float, float, float]:
    """(front_left, front_right, rear_left, rear_right) wheel speeds in rad/s.

    Standard X-roller mecanum (rollers form an X seen from above, the usual
    layout): with lx, ly the half wheelbase and half track,

        fl = (vx - vy - (lx + ly) wz) / r      fr = (vx + vy + (lx + ly) wz) / r
        rl = (vx + vy - (lx + ly) wz) / r      rr = (vx - vy + (lx + ly) wz) / r

    so a strafe to the left turns fl and rr backward and fr and rl forward.
    """
    _check_twist(twist)
    _check_length("wheelbase_m", wheelbase_m)
    _check_length("track_width_m", track_width_m)
    _check_length("wheel_radius_m", wheel_radius_m)
    vx, vy = twist.linear_x, twist.linear_y
    spin = (wheelbase_m / 2.0 + track_width_m / 2.0) * twist.angular_z
    r = wheel_radius_m
    return (
        (vx - vy - spin) / r,
        (vx + vy + spin) / r,
        (vx + vy - spin) / r,
        (vx - vy + spin) / r,
    )


def scale_to_limit(speeds: Sequence[float], max_speed: float) -> tuple[float, ...]:
    """Scale all ``speeds`` by one factor so none exceeds ``max_speed`` in magnitude.

    Clipping wheels one by one would change the ratio between them, and with it the
    direction of travel (a saturated turn becomes a wider arc, a mecanum strafe gains
    a spin); a common factor keeps the path and only slows it down.
    """
    if not math.isfinite(max_speed) or max_speed <= 0:
        raise ValueError(f"max_speed must be positive and finite, got {max_speed!r}")
    values = tuple(float(s) for s in speeds)
    for i, s in enumerate(values):
        if not math.isfinite(s):
            raise ValueError(f"wheel speed {i} is not finite: {s!r}")
    peak = max((abs(s) for s in values), default=0.0)
    if peak <= max_speed:
        return values
    factor = max_speed / peak
    return tuple(s * factor for s in values)


__all__ = ["differential", "mecanum", "scale_to_limit"]
