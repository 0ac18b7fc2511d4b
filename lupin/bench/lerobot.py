"""LeRobot calibration interop: its per-motor JSON, exported from and imported to this arm.

LeRobot (``lerobot/motors``) keeps one JSON object per robot: for each motor
name, ``{id, drive_mode, homing_offset, range_min, range_max}``. On Feetech
servos its ``homing_offset`` is the register 31 value itself
(``Present_Position = Actual_Position - Homing_Offset``, as here), and its
range is the raw recorded stops in the present (offset) frame. Its degree scale
puts 0 at the middle of that range, ``(present - mid) * 360 / 4095``, which is
where calibrate puts a joint's zero here, so the same physical pose reads the
same angle in both.

Export writes the swept range that ``arm.yaml`` recorded beside each joint (the
stops, as LeRobot's own calibrate would record them, so its -100..100 scale
matches an arm calibrated there); a joint with no sweep on record for the
offset it holds exports its soft limits instead. Import takes LeRobot's range
as the stops: the soft limits are pulled in from them by the margin, exactly
as calibrate pulls in a sweep, so export then import gives back the same
limits.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from lupin.bench.homing import OFFSET_LIMIT, CalibrationRefused, JointCalibration, pull_in
from lupin.config import ConfigError
from lupin.config_models import RobotProfile
from lupin.joints import COUNTS_PER_REV, RAD_PER_COUNT

FIELDS = ("id", "drive_mode", "homing_offset", "range_min", "range_max")


@dataclass(frozen=True)
class MotorCalibration:
    id: int
    drive_mode: int
    homing_offset: int
    range_min: int
    range_max: int


def export_calibration(
    profile: RobotProfile,
    offsets: Mapping[str, int],
    swept: Mapping[str, tuple[int, int]],
) -> dict[str, dict[str, int]]:
    """LeRobot's JSON shape for every arm joint whose offset was read.

    ``swept`` is each joint's recorded stops (counts, present frame); a joint
    missing from it exports its soft limits, which are inside the stops.
    """
    out = {}
    for j in profile.arm.joints:
        if j.name not in offsets:
            continue
        lo, hi = swept.get(j.name, (j.min, j.max))
        out[j.name] = {
            "id": j.id,
            "drive_mode": int(j.invert),
            "homing_offset": offsets[j.name],
            "range_min": max(0, lo),
            "range_max": min(COUNTS_PER_REV - 1, hi),
        }
    return out


def recorded_sweeps(
    overlay_joints: Mapping[str, Any], offsets: Mapping[str, int]
) -> dict[str, tuple[int, int]]:
    """The swept stops ``arm.yaml`` recorded, for joints still holding the offset they were
    measured about (a sweep about another offset names other positions)."""
    out = {}
    for name, entry in overlay_joints.items():
        m = entry.get("measurement") if isinstance(entry, dict) else None
        if not isinstance(m, dict) or m.get("homing_offset") != offsets.get(name):
            continue
        lo, hi = m.get("swept_min"), m.get("swept_max")
        if isinstance(lo, int) and isinstance(hi, int) and lo < hi:
            out[name] = (lo, hi)
    return out


def parse_calibration(data: Any, profile: RobotProfile, source: str) -> dict[str, MotorCalibration]:
    """Validate a LeRobot calibration against the profile; ConfigError naming motor and field."""
    if not isinstance(data, dict) or not data:
        raise ConfigError(f"{source}: expected a JSON object of motor names")
    joints = {j.name: j for j in profile.arm.joints}
    out: dict[str, MotorCalibration] = {}
    for name, entry in data.items():
        where = f"{source}: {name}"
        if name not in joints:
            raise ConfigError(f"{where}: not an arm joint of {profile.name} ({', '.join(joints)})")
        if not isinstance(entry, dict):
            raise ConfigError(f"{where}: expected an object with {', '.join(FIELDS)}")
        unknown = sorted(set(entry) - set(FIELDS))
        missing = [f for f in FIELDS if f not in entry]
        if unknown or missing:
            raise ConfigError(f"{where}: unknown fields {unknown}, missing {missing}")
        for f in FIELDS:
            if isinstance(entry[f], bool) or not isinstance(entry[f], int):
                raise ConfigError(f"{where}.{f}: expected an integer, got {entry[f]!r}")
        motor = MotorCalibration(**{f: entry[f] for f in FIELDS})
        joint = joints[name]
        if motor.id != joint.id:
            raise ConfigError(f"{where}.id: {motor.id}, but {name} is id {joint.id} here")
        if motor.drive_mode != int(joint.invert):
            # The direction is design, not calibration: a mismatch flips what radians mean.
            raise ConfigError(
                f"{where}.drive_mode: {motor.drive_mode}, but the profile has invert "
                f"{joint.invert}; fix the profile's direction first"
            )
        if abs(motor.homing_offset) > OFFSET_LIMIT:
            raise ConfigError(f"{where}.homing_offset: {motor.homing_offset} is outside ±2047")
        if not 0 <= motor.range_min < motor.range_max <= 4095:
            raise ConfigError(
                f"{where}: range {motor.range_min}..{motor.range_max} is not within 0..4095"
            )
        out[name] = motor
    return out


def full_turn(motor: MotorCalibration) -> bool:
    """LeRobot records a full-turn motor (the SO-101's wrist_roll) as the whole encoder."""
    return motor.range_max - motor.range_min >= COUNTS_PER_REV - 2


def plan_import(
    profile: RobotProfile,
    motors: Mapping[str, MotorCalibration],
    old_offsets: Mapping[str, int],
    source: str,
    margin_rad: float,
) -> list[JointCalibration]:
    """One JointCalibration per imported motor, in profile order.

    Raises ConfigError naming the motor whose range is too short for the margin.
    """
    out = []
    for joint in profile.arm.joints:
        motor = motors.get(joint.name)
        if motor is None:
            continue
        try:
            lo, hi = pull_in(joint.name, motor.range_min, motor.range_max, margin_rad)
        except CalibrationRefused as exc:
            raise ConfigError(f"{source}: {exc}") from None
        out.append(
            JointCalibration(
                name=joint.name,
                id=joint.id,
                invert=joint.invert,
                old_offset=old_offsets[joint.name],
                new_offset=motor.homing_offset,
                old_zero=joint.zero,
                zero=round((motor.range_min + motor.range_max) / 2),
                min=lo,
                max=hi,
                measurement={
                    "lerobot_file": source,
                    "swept_min": motor.range_min,
                    "swept_max": motor.range_max,
                    "swept_rad": round((motor.range_max - motor.range_min) * RAD_PER_COUNT, 4),
                    "margin_rad": margin_rad,
                    "homing_offset": motor.homing_offset,
                    "previous_homing_offset": old_offsets[joint.name],
                },
            )
        )
    return out
