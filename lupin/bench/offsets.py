"""Homing offsets (register 31): read, back up, restore, and the verified one-servo-at-a-time write.

The offset lives only in the servo, so overwriting it destroys the previous
value. Every tool that writes one snapshots the existing offsets first to
``$LUPIN_HOME/arm_offsets_backup.yaml``; then each servo is written, confirmed
by a double read-back, and checked to have moved its present reading by
exactly the delta written before the next is touched. The first failure stops
everything and says which servos were already changed (bring-up seed: an
earlier tool died mid-run on a dropped read, with no backup to go back to).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import yaml

from lupin.bench.files import write_text_atomic
from lupin.bench.homing import OFFSET_LIMIT, wrap
from lupin.bench.registers import EepromWriteFailed, ServoIO
from lupin.config import ConfigError, read_yaml
from lupin.config_models import JointConfig

BACKUP_NAME = "arm_offsets_backup.yaml"
# What a restore overwrote, kept apart from the backup it restored from, so a
# restore from the wrong snapshot can be undone.
BEFORE_RESTORE_NAME = "arm_offsets_before_restore.yaml"
RESTORE_COMMAND = "lupin offsets restore"
# A limp joint's encoder may tick a count between the two reads; a wrong write
# moves the reading by the whole delta, so two counts separates them cleanly.
VERIFY_TOLERANCE = 2


@dataclass(frozen=True)
class OffsetChange:
    """One servo's offset going from ``old`` to ``new``."""

    name: str
    id: int
    old: int
    new: int

    def describe(self) -> str:
        return f"{self.name} (id {self.id}): homing offset {self.old} -> {self.new}"


class OffsetReadFailed(Exception):
    """Some servos' offsets could not be read; nothing was written."""


class OffsetWriteFailed(Exception):
    """A write failed; ``changed`` were verified written before it, ``failed`` is the culprit."""

    def __init__(
        self, changed: list[OffsetChange], failed: OffsetChange, reason: str, maybe: bool
    ) -> None:
        super().__init__(f"{failed.name} (id {failed.id}): {reason}")
        self.changed = changed
        self.failed = failed
        self.reason = reason
        self.maybe_changed = maybe  # the failed servo may hold the new value

    @property
    def touched(self) -> list[OffsetChange]:
        """Every servo that holds, or may hold, a new offset."""
        return [*self.changed, *([self.failed] if self.maybe_changed else [])]


class _Failed(Exception):
    def __init__(self, reason: str, maybe: bool) -> None:
        super().__init__(reason)
        self.maybe = maybe


async def read_offsets(io: ServoIO, joints: Sequence[JointConfig]) -> dict[str, int]:
    """Every joint's homing offset, double-read; raises naming the servos that did not answer."""
    out: dict[str, int] = {}
    silent = []
    for j in joints:
        got = await io.read_confirmed(j.id, ["homing_offset"])
        if got is None:
            silent.append(f"{j.name} (id {j.id})")
        else:
            out[j.name] = got["homing_offset"]
    if silent:
        raise OffsetReadFailed(f"no confirmed read of the homing offset from {', '.join(silent)}")
    return out


# -- the backup file ------------------------------------------------------------


def write_backup(
    path: Path,
    offsets: dict[str, int],
    joints: Sequence[JointConfig],
    *,
    profile: str,
    port: str,
    now: datetime | None = None,
) -> Path | None:
    """Write the snapshot atomically; an earlier backup is kept beside it, stamped.

    Returns where the earlier backup went (None if there was none). It is kept
    because a second run after an interrupted one would otherwise overwrite the
    only record of the original offsets with half-changed ones.
    """
    now = now or datetime.now().astimezone()
    archived = None
    if path.exists():
        stamp = datetime.fromtimestamp(path.stat().st_mtime).strftime("%Y%m%d-%H%M%S")
        archived = path.with_name(f"{path.stem}.{stamp}{path.suffix}")
        n = 1
        while archived.exists():  # two backups in one second must not overwrite each other
            n += 1
            archived = path.with_name(f"{path.stem}.{stamp}-{n}{path.suffix}")
        path.replace(archived)
    ids = {j.name: j.id for j in joints}
    body = {
        "taken": now.isoformat(timespec="seconds"),
        "profile": profile,
        "port": port,
        "joints": {n: {"id": ids[n], "homing_offset": v} for n, v in offsets.items()},
    }
    header = (
        "# Servo homing offsets (register 31) as read before a write, the only copy of\n"
        f"# values the servos no longer hold. Put them back with: {RESTORE_COMMAND}\n"
    )
    write_text_atomic(path, header + yaml.safe_dump(body, sort_keys=False))
    return archived


def read_backup(path: Path, joints: Sequence[JointConfig]) -> dict[str, int]:
    """The offsets in a backup file, checked against the profile's joints and ids."""
    raw = read_yaml(path)
    entries = raw.get("joints")
    if not isinstance(entries, dict) or not entries:
        raise ConfigError(f"{path}: joints: expected a mapping of joint names")
    by_name = {j.name: j for j in joints}
    out: dict[str, int] = {}
    for name, entry in entries.items():
        where = f"{path}: joints.{name}"
        if name not in by_name:
            raise ConfigError(f"{where}: not a joint of this profile ({', '.join(by_name)})")
        if not isinstance(entry, dict) or set(entry) != {"id", "homing_offset"}:
            raise ConfigError(f"{where}: expected {{id, homing_offset}}")
        if entry["id"] != by_name[name].id:
            raise ConfigError(f"{where}.id: {entry['id']} but the profile says {by_name[name].id}")
        out[name] = _offset_value(entry["homing_offset"], f"{where}.homing_offset")
    return out


def _offset_value(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or abs(value) > OFFSET_LIMIT:
        raise ConfigError(f"{where}: expected an integer within ±{OFFSET_LIMIT}, got {value!r}")
    return value


# -- writing -------------------------------------------------------------------------


async def relock(io: ServoIO, joints: Sequence[JointConfig]) -> list[JointConfig]:
    """Lock EEPROM on any joint found unlocked; the ones relocked.

    A write interrupted between unlock and relock (a servo that dropped off the
    bus mid-write) leaves its EEPROM open to any stray write until power-off.
    """
    done = []
    for j in joints:
        if await io.read(j.id, "lock") == 0 and await io.write(j.id, "lock", 1):
            done.append(j)
    return done


async def write_offsets(
    io: ServoIO, changes: Sequence[OffsetChange], *, tolerance: int = VERIFY_TOLERANCE
) -> list[OffsetChange]:
    """Write and verify one servo at a time; the first failure raises OffsetWriteFailed."""
    done: list[OffsetChange] = []
    for change in changes:
        if change.new == change.old:
            continue
        try:
            await _write_one(io, change, tolerance)
        except _Failed as exc:
            raise OffsetWriteFailed(done, change, str(exc), exc.maybe) from None
        done.append(change)
    return done


async def _write_one(io: ServoIO, change: OffsetChange, tolerance: int) -> None:
    sid = change.id
    torque = await io.read(sid, "torque_enable")
    if torque is None:
        raise _Failed("no reply reading torque_enable", False)
    if torque:
        # In a new frame the held goal names another place: the joint would jump.
        raise _Failed("torque is on; an offset written under torque moves the joint", False)
    before = await io.read(sid, "present_position")
    current = await io.read_confirmed(sid, ["homing_offset"])
    if before is None or current is None:
        raise _Failed("no reply reading the position and offset before the write", False)
    if current["homing_offset"] != change.old:
        raise _Failed(
            f"its offset reads {current['homing_offset']}, not the {change.old} planned from; "
            f"something else changed it",
            False,
        )
    try:
        await io.write_eeprom(sid, {"homing_offset": change.new})
    except EepromWriteFailed as exc:
        raise _Failed(str(exc).split(": ", 1)[-1], True) from None
    after = await io.read(sid, "present_position")
    if after is None:
        raise _Failed("offset written, but no reply reading the position after it", True)
    moved = wrap(before - after)
    want = wrap(change.new - change.old)
    if abs(wrap(moved - want)) > tolerance:
        raise _Failed(
            f"offset reads back {change.new} but the reading moved by {moved} counts, "
            f"not the {want} written",
            True,
        )
