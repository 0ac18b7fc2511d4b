"""LeRobot calibration interop: its per-motor JSON, exported from and imported to this arm.

LeRobot (``lerobot/motors``) keeps one JSON object per robot: for each motor
name, ``{id, drive_mode, homing_offset, range_min, range_max}``. On Feetech
servos its ``homing_offset`` is the register 31 value itself
(``Present_Position = Actual_Position - Homing_Offset``, as here), and its
range is in the present (offset) frame, which it writes to the servo's
position-limit registers.

Export writes Lupin's soft limits as the range: the swept range pulled in by
the margin, stricter than LeRobot's raw stops, so it is safe in both
directions. Import writes the offsets (with the same backup and verified
write as calibrate) and takes the range as this arm's limits with the zero at
its middle, which is where LeRobot's own degree scale puts 0.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from lupin.bench.homing import OFFSET_LIMIT, JointCalibration
from lupin.config import ConfigError
from lupin.config_models import RobotProfile

FIELDS = ("id", "drive_mode", "homing_offset", "range_min", "range_max")


@dataclass(frozen=True)
class MotorCalibration:
    id: int
    drive_mode: int
    homing_offset: int
    range_min: int
    range_max: int


def export_calibration(
    profile: RobotProfile, offsets: Mapping[str, int]
) -> dict[str, dict[str, int]]:
    """LeRobot's JSON shape for every arm joint whose offset was read."""
    return {
        j.name: {
            "id": j.id,
            "drive_mode": int(j.invert),
            "homing_offset": offsets[j.name],
            "range_min": j.min,
            "range_max": j.max,
        }
        for j in profile.arm.joints
        if j.name in offsets
    }


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


def plan_import(
    profile: RobotProfile,
    motors: Mapping[str, MotorCalibration],
    old_offsets: Mapping[str, int],
    source: str,
) -> list[JointCalibration]:
    """One JointCalibration per imported motor, in profile order."""
    out = []
    for joint in profile.arm.joints:
        motor = motors.get(joint.name)
        if motor is None:
            continue
        out.append(
            JointCalibration(
                name=joint.name,
                id=joint.id,
                invert=joint.invert,
                old_offset=old_offsets[joint.name],
                new_offset=motor.homing_offset,
                old_zero=joint.zero,
                zero=round((motor.range_min + motor.range_max) / 2),
                min=motor.range_min,
                max=motor.range_max,
                measurement={
                    "lerobot_file": source,
                    "range_min": motor.range_min,
                    "range_max": motor.range_max,
                    "homing_offset": motor.homing_offset,
                    "previous_homing_offset": old_offsets[joint.name],
                },
            )
        )
    return out
