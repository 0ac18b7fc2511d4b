"""Calibration phase 2 as a whole: prepare everything without writing, then commit in order.

``prepare`` builds and validates the new ``arm.yaml`` and the migrated poses
before any servo is touched, so nothing can fail after the EEPROM writes that
could have been caught before them. ``commit`` then runs the seed's order:
snapshot the offsets, write them one servo at a time (verified), save
``arm.yaml``, migrate the poses keeping ``poses.yaml.bak``.

Poses are radians about the zero, so moving a zero changes which physical
position each number names; the correction is exactly the shift computed
here, so they are rewritten rather than re-taught. A pose that lands outside
the new limits is named, never clamped: it was taught somewhere the arm can no
longer reach, which is a decision, not arithmetic (bring-up seed).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from lupin.bench.homing import JointCalibration
from lupin.bench.offsets import BACKUP_NAME, OffsetChange, write_backup, write_offsets
from lupin.bench.overlay_file import OVERLAY_NAME, build_overlay, save_overlay, validate_overlay
from lupin.bench.registers import ServoIO
from lupin.config_models import RobotProfile
from lupin.poses import PoseStore

POSES_NAME = "poses.yaml"

Poses = dict[str, dict[str, float]]


@dataclass(frozen=True)
class PoseOutside:
    pose: str
    joint: str
    rad: float
    lo: float
    hi: float


@dataclass
class PreparedCalibration:
    """Everything phase 2 will do, computed and validated; nothing written yet."""

    calibrations: list[JointCalibration]
    overlay: dict[str, Any]
    overlay_path: Path
    backup_path: Path
    profile: RobotProfile  # as it will load with the new overlay
    poses: PoseStore
    poses_before: Poses
    poses_after: Poses
    outside: list[PoseOutside]

    @property
    def changes(self) -> list[OffsetChange]:
        """The offsets that actually change (an unchanged one is not written)."""
        return [
            OffsetChange(c.name, c.id, c.old_offset, c.new_offset)
            for c in self.calibrations
            if c.new_offset != c.old_offset
        ]

    @property
    def poses_changed(self) -> bool:
        return self.poses_after != self.poses_before


@dataclass
class CommitResult:
    written: list[OffsetChange]
    archived_backup: Path | None
    poses_migrated: bool


def migrate_poses(poses: Poses, shifts: Mapping[str, float]) -> Poses:
    """Every pose re-expressed about the new zeros: each joint moved by its shift."""
    return {
        name: {j: rad + shifts.get(j, 0.0) for j, rad in pose.items()}
        for name, pose in poses.items()
    }


def poses_outside(poses: Poses, limits: Mapping[str, tuple[float, float]]) -> list[PoseOutside]:
    out = []
    for name, pose in poses.items():
        for joint, rad in pose.items():
            if joint in limits:
                lo, hi = limits[joint]
                if not lo - 1e-9 <= rad <= hi + 1e-9:
                    out.append(PoseOutside(name, joint, rad, lo, hi))
    return out


def prepare(
    profile: RobotProfile,
    calibrations: Sequence[JointCalibration],
    *,
    home: Path,
    profile_arg: str | None,
    config_file: str | None,
    source: str,
    now: datetime | None = None,
) -> PreparedCalibration:
    """Compute and validate; raises ConfigError (bad poses file, an overlay that would not load)."""
    stamp = (now or datetime.now().astimezone()).isoformat(timespec="seconds")
    overlay_path = home / OVERLAY_NAME
    overlay = build_overlay(overlay_path, calibrations, stamp=stamp, source=source)
    new_profile = validate_overlay(overlay, profile=profile_arg, config_file=config_file)
    store = PoseStore(home / POSES_NAME, [j.name for j in profile.arm.joints])
    before = store.load()
    shifts = {c.name: c.shift_rad for c in calibrations}
    after = migrate_poses(before, shifts)
    outside = poses_outside(after, {c.name: c.limits_rad for c in calibrations})
    return PreparedCalibration(
        calibrations=list(calibrations),
        overlay=overlay,
        overlay_path=overlay_path,
        backup_path=home / BACKUP_NAME,
        profile=new_profile,
        poses=store,
        poses_before=before,
        poses_after=after,
        outside=outside,
    )


async def commit(
    io: ServoIO, prepared: PreparedCalibration, *, profile_name: str, port: str
) -> CommitResult:
    """Back up, write the offsets (raises OffsetWriteFailed), save arm.yaml, migrate poses."""
    archived = None
    written: list[OffsetChange] = []
    changes = prepared.changes
    if changes:
        joints = [j for j in prepared.profile.arm.joints if j.name in {c.name for c in changes}]
        archived = write_backup(
            prepared.backup_path,
            {c.name: c.old for c in changes},
            joints,
            profile=profile_name,
            port=port,
        )
        written = await write_offsets(io, changes)
    save_overlay(prepared.overlay_path, prepared.overlay)
    if prepared.poses_changed:
        prepared.poses.save_all(prepared.poses_after)
    return CommitResult(written, archived, prepared.poses_changed)
