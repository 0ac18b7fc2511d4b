"""``lupin offsets show|backup|restore|set|export-lerobot|import-lerobot``: the recovery path.

The homing offsets live only in the servos. ``backup`` snapshots them,
``restore`` writes a snapshot back (each servo verified), ``set`` writes them
by hand (after a backup), and the LeRobot pair moves a calibration between
Lupin and LeRobot's per-motor JSON.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from lupin.bench.calibration import commit, prepare
from lupin.bench.files import write_text_atomic
from lupin.bench.homing import OFFSET_LIMIT, fold_offset
from lupin.bench.lerobot import (
    export_calibration,
    full_turn,
    parse_calibration,
    plan_import,
    recorded_sweeps,
)
from lupin.bench.offsets import (
    BACKUP_NAME,
    BEFORE_RESTORE_NAME,
    OffsetChange,
    OffsetReadFailed,
    OffsetWriteFailed,
    read_backup,
    read_offsets,
    relock,
    write_backup,
    write_offsets,
)
from lupin.bench.overlay_file import OVERLAY_NAME
from lupin.bench.registers import ServoIO
from lupin.bench.session import open_bench_bus
from lupin.cli.bench_io import (
    EXIT_FAILED,
    EXIT_OK,
    Terminal,
    UsageError,
    load,
    port_of,
    release_torque,
    restore_command,
    run_tool,
    warn_servo_limits,
)
from lupin.config import ConfigError, lupin_home, read_yaml
from lupin.config_models import JointConfig, RobotProfile


def main(args: argparse.Namespace) -> int:
    profile = load(args)
    term = Terminal(args.yes)
    actions = {
        "show": show,
        "backup": backup,
        "restore": restore,
        "set": set_offsets,
        "export-lerobot": export_lerobot,
        "import-lerobot": import_lerobot,
    }
    action = actions[args.action]
    return run_tool(f"offsets {args.action}", lambda: action(args, profile, term))


def overlay_joints(home: Path) -> dict[str, Any]:
    """The ``joints`` mapping of ``arm.yaml`` as written (empty without one)."""
    path = home / OVERLAY_NAME
    if not path.exists():
        return {}
    joints = read_yaml(path).get("joints") or {}
    return joints if isinstance(joints, dict) else {}


def recorded_offsets(home: Path) -> dict[str, int]:
    """The homing offsets arm.yaml says were written, by joint (empty without one)."""
    out = {}
    for name, entry in overlay_joints(home).items():
        value = ((entry or {}).get("measurement") or {}).get("homing_offset")
        if isinstance(value, int):
            out[name] = value
    return out


def warn_overlay(term: Terminal, offsets: dict[str, int]) -> None:
    """Say which joints' arm.yaml was measured about offsets they no longer hold."""
    recorded = recorded_offsets(lupin_home())
    stale = [n for n, v in offsets.items() if n in recorded and recorded[n] != v]
    if stale:
        term.say(
            f"Note: arm.yaml was calibrated with other offsets for {', '.join(stale)}; its zero "
            f"and limits (and taught poses) no longer match them: re-run lupin calibrate."
        )


async def show(args: argparse.Namespace, profile: RobotProfile, term: Terminal) -> int:
    recorded = recorded_offsets(lupin_home())
    unread = 0
    async with open_bench_bus(profile, args.bus_port) as bus:
        io = ServoIO(bus)
        term.say(f"{'joint':<14} {'id':>3} {'offset':>7}  arm.yaml")
        for j in profile.arm.joints:
            got = await io.read_confirmed(j.id, ["homing_offset"])
            value = "?" if got is None else str(got["homing_offset"])
            unread += got is None
            note = str(recorded.get(j.name, "-"))
            if got is not None and j.name in recorded and recorded[j.name] != got["homing_offset"]:
                note += "  (differs)"
            term.say(f"{j.name:<14} {j.id:>3} {value:>7}  {note}")
    return EXIT_FAILED if unread else EXIT_OK


def backup_file(args: argparse.Namespace) -> Path:
    return Path(args.file) if args.file else lupin_home() / BACKUP_NAME


async def backup(args: argparse.Namespace, profile: RobotProfile, term: Terminal) -> int:
    path = backup_file(args)
    async with open_bench_bus(profile, args.bus_port) as bus:
        try:
            offsets = await read_offsets(ServoIO(bus), profile.arm.joints)
        except OffsetReadFailed as exc:
            term.say(f"Refused: {exc}. No backup written.")
            return EXIT_FAILED
    archived = write_backup(
        path, offsets, profile.arm.joints, profile=profile.name, port=port_of(args, profile)
    )
    term.say(f"Backed up {len(offsets)} offsets to {path}.")
    if archived is not None:
        term.say(f"(the previous backup was kept as {archived})")
    return EXIT_OK


def report_failure(exc: OffsetWriteFailed, args: argparse.Namespace, term: Terminal) -> None:
    term.say(f"Stopped: {exc}")
    done = ", ".join(f"{c.name} (id {c.id})" for c in exc.touched) or "none"
    term.say(f"Changed (or possibly changed): {done}. Recover with: {restore_command(args)}")


async def write_changes(
    io: ServoIO,
    changes: list[OffsetChange],
    joints: list[JointConfig],
    args: argparse.Namespace,
    term: Terminal,
    *,
    backup: Callable[[], None] | None = None,
) -> int:
    """Show the EEPROM writes, ask once, limp the joints, back up, write and verify each."""
    if not changes:
        term.say("Every offset already holds that value; nothing to write.")
        return EXIT_OK
    term.say("EEPROM writes (register 31, persistent):")
    for c in changes:
        term.say(f"  {c.describe()}")
    if not await term.confirm("Write these offsets?"):
        term.say("Nothing was written.")
        return EXIT_FAILED
    if not await release_torque(io, joints, term):
        return EXIT_FAILED
    if backup is not None:
        backup()
    try:
        written = await write_offsets(io, changes)
    except OffsetWriteFailed as exc:
        report_failure(exc, args, term)
        return EXIT_FAILED
    for c in written:
        term.say(f"wrote and verified {c.describe()}")
    return EXIT_OK


async def restore(args: argparse.Namespace, profile: RobotProfile, term: Terminal) -> int:
    path = backup_file(args)
    wanted = read_backup(path, profile.arm.joints)
    joints = [j for j in profile.arm.joints if j.name in wanted]
    term.say(f"Restoring the offsets in {path}.")
    async with open_bench_bus(profile, args.bus_port) as bus:
        io = ServoIO(bus)
        try:
            current = await read_offsets(io, joints)
        except OffsetReadFailed as exc:
            term.say(f"Refused: {exc}. Nothing was written.")
            return EXIT_FAILED
        changes = [
            OffsetChange(j.name, j.id, current[j.name], wanted[j.name])
            for j in joints
            if current[j.name] != wanted[j.name]
        ]
        undo = lupin_home() / BEFORE_RESTORE_NAME
        if undo.resolve() == path.resolve():
            undo = undo.with_name(f"{undo.stem}.undo{undo.suffix}")

        def snapshot() -> None:
            # The offsets about to be overwritten exist nowhere else: keep them too.
            old = {c.name: c.old for c in changes}
            write_backup(undo, old, joints, profile=profile.name, port=port_of(args, profile))
            term.say(
                f"Saved the offsets being replaced to {undo} "
                f"(undo with: {restore_command(args)} --file {undo})."
            )

        code = await write_changes(io, changes, joints, args, term, backup=snapshot)
        for j in await relock(io, joints):
            term.say(f"{j.name} (id {j.id}) was left with EEPROM unlocked; locked it again.")
    if code == EXIT_OK:
        warn_overlay(term, wanted)
    return code


async def set_offsets(args: argparse.Namespace, profile: RobotProfile, term: Terminal) -> int:
    names = [j.name for j in profile.arm.joints]
    wanted: dict[str, int] = {}
    for name, value in args.values:
        if name not in names:
            raise UsageError(f"unknown joint {name!r}; this arm has {', '.join(names)}")
        folded = fold_offset(value)
        if folded != value:
            # Offsets are modular: fold, never reject (bring-up seed).
            term.say(f"{name}: {value} folded modulo 4096 into ±{OFFSET_LIMIT}: {folded}")
        wanted[name] = folded
    joints = [j for j in profile.arm.joints if j.name in wanted]
    async with open_bench_bus(profile, args.bus_port) as bus:
        io = ServoIO(bus)
        try:
            current = await read_offsets(io, joints)
        except OffsetReadFailed as exc:
            term.say(f"Refused: {exc}. Nothing was written.")
            return EXIT_FAILED
        changes = [
            OffsetChange(j.name, j.id, current[j.name], wanted[j.name])
            for j in joints
            if current[j.name] != wanted[j.name]
        ]

        def snapshot() -> None:
            # Only once the operator said yes: a backup archives the previous one.
            path = lupin_home() / BACKUP_NAME
            old = {c.name: c.old for c in changes}
            kept = write_backup(
                path, old, joints, profile=profile.name, port=port_of(args, profile)
            )
            term.say(f"Backed up the current offsets to {path}.")
            if kept is not None:
                term.say(f"(the previous backup was kept as {kept})")

        code = await write_changes(io, changes, joints, args, term, backup=snapshot)
    if code == EXIT_OK and changes:
        warn_overlay(term, wanted)
    return code


async def export_lerobot(args: argparse.Namespace, profile: RobotProfile, term: Terminal) -> int:
    async with open_bench_bus(profile, args.bus_port) as bus:
        try:
            offsets = await read_offsets(ServoIO(bus), profile.arm.joints)
        except OffsetReadFailed as exc:
            term.say(f"Refused: {exc}. Nothing was exported.")
            return EXIT_FAILED
    swept = recorded_sweeps(overlay_joints(lupin_home()), offsets)
    data = export_calibration(profile, offsets, swept)
    write_text_atomic(Path(args.file), json.dumps(data, indent=4) + "\n")
    term.say(f"Exported {len(data)} motors to {args.file} (LeRobot calibration JSON).")
    limits_only = [name for name in data if name not in swept]
    if limits_only:
        term.say(
            f"No sweep on record for the offsets {', '.join(limits_only)} hold: their range is "
            f"the soft limits (inside the stops). Run lupin calibrate to export the stops."
        )
    return EXIT_OK


def read_json(path: Path) -> object:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: cannot read LeRobot calibration: {exc}") from None


async def import_lerobot(args: argparse.Namespace, profile: RobotProfile, term: Terminal) -> int:
    source = Path(args.file)
    motors = parse_calibration(read_json(source), profile, str(source))
    joints = [j for j in profile.arm.joints if j.name in motors]
    async with open_bench_bus(profile, args.bus_port) as bus:
        io = ServoIO(bus)
        try:
            old = await read_offsets(io, joints)
        except OffsetReadFailed as exc:
            term.say(f"Refused: {exc}. Nothing was written.")
            return EXIT_FAILED
        try:
            calibrations = plan_import(profile, motors, old, str(source), args.margin)
            prepared = prepare(
                profile,
                calibrations,
                home=lupin_home(),
                profile_arg=args.profile,
                config_file=args.config,
                source=f"lupin offsets import-lerobot {source}",
            )
        except ConfigError as exc:
            term.say(f"Refused:\n{exc}\nNothing was written.")
            return EXIT_FAILED
        if prepared.changes:
            term.say("EEPROM writes (register 31, persistent):")
            for c in prepared.changes:
                term.say(f"  {c.describe()}")
            term.say(f"The current offsets are backed up to {prepared.backup_path} first.")
            if not await term.confirm("Write these offsets?"):
                term.say("Nothing was written.")
                return EXIT_FAILED
            if not await release_torque(io, joints, term):
                return EXIT_FAILED
        try:
            port = port_of(args, profile)
            result = await commit(io, prepared, profile_name=profile.name, port=port)
        except OffsetWriteFailed as exc:
            report_failure(exc, args, term)
            return EXIT_FAILED
        for c in result.written:
            term.say(f"wrote and verified {c.describe()}")
        term.say(f"Saved the imported calibration to {prepared.overlay_path}.")
        await warn_servo_limits(io, prepared.calibrations, term)
    for name, motor in motors.items():
        if full_turn(motor):
            term.say(
                f"{name}: LeRobot's range is the whole turn (a full-turn motor there); here its "
                f"window is the profile's envelope about the middle of that turn."
            )
    if result.poses_migrated:
        bak = f"{prepared.poses.path.name}.bak"
        term.say(f"Migrated the taught poses (previous file kept as {bak}).")
    for o in prepared.outside:
        term.say(f"Pose {o.pose!r} is now outside {o.joint}'s limits ({o.rad:+.3f} rad).")
    return EXIT_OK
