"""The mobile base: a twist from the mux to wheel goal speeds, with its own timeout.

The mux outputs nothing when no source is active; like a ROS base controller the
base then stops on its own command timeout, counted from when the winning source
last published, so a silent commander stops the wheels whatever the mux does.
"""

from __future__ import annotations

import math

from lupin import kinematics
from lupin.config_models import BaseConfig
from lupin.joints import COUNTS_PER_REV
from lupin.mux import Twist

COUNTS_PER_RAD = COUNTS_PER_REV / (2 * math.pi)
# Goal speed register: sign-magnitude, 15 bits of steps per second.
MAX_SPEED_REGISTER = 0x7FFF


class BaseDrive:
    """Turns the latest twist into per-wheel goal speeds (encoder counts per second)."""

    def __init__(self, config: BaseConfig) -> None:
        self.config = config
        self.wheel_ids = [w.id for w in config.wheels]
        self._signs = [-1 if w.invert else 1 for w in config.wheels]
        self._twist: Twist | None = None
        self._stamp = -math.inf
        self.stopped_by: str | None = "idle"

    def command(self, twist: Twist | None, stamp: float) -> None:
        """The mux's output this tick and when its source last published (monotonic s)."""
        if twist is not None:
            self._twist, self._stamp = twist, stamp

    def stop(self) -> None:
        """Forget the last command: the wheels go to zero on the next tick."""
        self._twist, self._stamp = None, -math.inf

    def current_twist(self, now: float) -> Twist | None:
        if self._twist is None or now - self._stamp > self.config.command_timeout_s:
            return None
        return self._twist

    def wheel_speeds_rad_s(self, now: float) -> tuple[float, ...]:
        twist = self.current_twist(now)
        if twist is None or twist.is_zero():
            return tuple(0.0 for _ in self.wheel_ids)
        c = self.config
        if c.kind == "differential":
            speeds: tuple[float, ...] = kinematics.differential(
                twist, c.track_width_m, c.wheel_radius_m
            )
        else:
            assert c.wheelbase_m is not None  # validated at load
            speeds = kinematics.mecanum(twist, c.wheelbase_m, c.track_width_m, c.wheel_radius_m)
        return kinematics.scale_to_limit(speeds, c.max_wheel_speed_rad_s)

    def wheel_goals(self, now: float) -> dict[int, int]:
        """Goal speed register values per wheel servo id."""
        out = {}
        for sid, sign, rad_s in zip(
            self.wheel_ids, self._signs, self.wheel_speeds_rad_s(now), strict=True
        ):
            counts = round(sign * rad_s * COUNTS_PER_RAD)
            out[sid] = max(-MAX_SPEED_REGISTER, min(MAX_SPEED_REGISTER, counts))
        return out
