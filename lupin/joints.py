"""Joint geometry: encoder counts <-> radians, and each joint's window.

The window is computed here and nowhere else (the runbook's arm_limits was the
single source of truth for sliders, presets and teleop; so is this). It is the
servo's software limit intersected with the joint's envelope (±90° unless set),
rounded inward to whole degrees, so a goal inside the window is always one the
servo will accept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from lupin.config_models import ArmConfig, JointConfig

COUNTS_PER_REV = 4096
RAD_PER_COUNT = 2 * math.pi / COUNTS_PER_REV


@dataclass(frozen=True, slots=True)
class JointGeometry:
    """Everything the control tick needs to convert one joint, precomputed."""

    name: str
    id: int
    zero: int
    min_counts: int
    max_counts: int
    sign: int
    window_deg: tuple[int, int]

    @property
    def window_rad(self) -> tuple[float, float]:
        return math.radians(self.window_deg[0]), math.radians(self.window_deg[1])

    def counts_to_rad(self, counts: int) -> float:
        return self.sign * (counts - self.zero) * RAD_PER_COUNT

    def rad_to_counts(self, rad: float) -> int:
        """Radians to a goal register value, clamped to the servo's limits."""
        counts = round(self.zero + self.sign * rad / RAD_PER_COUNT)
        return min(max(counts, self.min_counts), self.max_counts)

    def clamp_rad(self, rad: float) -> float:
        lo, hi = self.window_rad
        return min(max(rad, lo), hi)

    def in_window(self, rad: float) -> bool:
        lo, hi = self.window_rad
        return lo - 1e-9 <= rad <= hi + 1e-9


def joint_window_deg(joint: JointConfig, envelope_deg: float) -> tuple[int, int]:
    """Servo limit ∩ envelope, rounded inward to whole degrees."""
    sign = -1 if joint.invert else 1
    a = sign * (joint.min - joint.zero) * RAD_PER_COUNT
    b = sign * (joint.max - joint.zero) * RAD_PER_COUNT
    servo_lo, servo_hi = math.degrees(min(a, b)), math.degrees(max(a, b))
    env = joint.envelope_deg if joint.envelope_deg is not None else envelope_deg
    # A tiny epsilon keeps 89.99999999 (float noise from counts) from rounding to 89.
    lo = math.ceil(max(servo_lo, -env) - 1e-9)
    hi = math.floor(min(servo_hi, env) + 1e-9)
    return lo, hi


def geometry(joint: JointConfig, envelope_deg: float) -> JointGeometry:
    return JointGeometry(
        name=joint.name,
        id=joint.id,
        zero=joint.zero,
        min_counts=joint.min,
        max_counts=joint.max,
        sign=-1 if joint.invert else 1,
        window_deg=joint_window_deg(joint, envelope_deg),
    )


def arm_geometry(arm: ArmConfig) -> dict[str, JointGeometry]:
    return {j.name: geometry(j, arm.envelope_deg) for j in arm.joints}
