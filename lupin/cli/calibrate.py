"""``lupin calibrate``: sweep every joint's range, centre its zero, save ``$LUPIN_HOME/arm.yaml``.

Phase 1 releases torque (asking first, unless the torque register already
reads off: an unsupported arm falls), then one live table records every
joint while the operator moves each to both stops; Enter ends it. Phase 2
shows the EEPROM writes and asks once, then backs up, writes and verifies one
servo at a time, saves and migrates the poses. ``--skip-homing`` records the
ranges only and writes no EEPROM.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import time
from typing import TextIO

from lupin.bench.calibration import PreparedCalibration, commit, prepare
from lupin.bench.homing import CalibrationRefused, JointCalibration, plan_joint
from lupin.bench.offsets import OffsetReadFailed, OffsetWriteFailed, read_offsets
from lupin.bench.registers import ServoIO
from lupin.bench.session import open_bench_bus
from lupin.bench.sweep import SweepRecorder, record_sweep
from lupin.bus import ServoBus
from lupin.cli.bench_io import (
    EXIT_FAILED,
    EXIT_OK,
    Terminal,
    load,
    port_of,
    release_torque,
    restore_command,
    run_tool,
    select_joints,
    warn_servo_limits,
)
from lupin.config import ConfigError, lupin_home
from lupin.config_models import JointConfig, RobotProfile

REDRAW_S = 0.1


class LiveTable:
    """The phase-1 table, redrawn in place on a terminal; printed once at the end otherwise."""

    def __init__(self, out: TextIO, live: bool) -> None:
        self.out = out
        self.live = live
        self._drawn = 0
        self._last = 0.0

    def update(self, rec: SweepRecorder) -> None:
        now = time.monotonic()
        if self.live and now - self._last >= REDRAW_S:
            self._last = now
            self.draw(rec)

    def draw(self, rec: SweepRecorder) -> None:
        lines = self.render(rec)
        if self._drawn and self.live:
            self.out.write(f"\x1b[{self._drawn}F")  # back to the table's first line
        self.out.write("".join(f"\x1b[2K{line}\n" if self.live else f"{line}\n" for line in lines))
        self.out.flush()
        self._drawn = len(lines)

    @staticmethod
    def render(rec: SweepRecorder) -> list[str]:
        lines = [f"  {'joint':<14} {'now':>6} {'min':>6} {'max':>6} {'range':>10}  samples"]
        for t in rec.traces.values():
            if t.samples == 0:
                lines.append(f"  {t.name:<14} {'-- no reading yet --':>32}")
                continue
            wrap = "  crossed 0/4095" if t.crossings else ""
            lines.append(
                f"  {t.name:<14} {t.now:>6} {t.lo:>6} {t.hi:>6} {t.span_rad:>6.2f} rad  "
                f"{t.samples:>7}{wrap}"
            )
        return lines


def main(args: argparse.Namespace) -> int:
    profile = load(args)
    term = Terminal(args.yes)
    return run_tool("calibrate", lambda: calibrate(args, profile, term))


async def calibrate(args: argparse.Namespace, profile: RobotProfile, term: Terminal) -> int:
    joints = select_joints(profile, args.joints)
    homing = not args.skip_homing
    port = port_of(args, profile)
    async with open_bench_bus(profile, args.bus_port) as bus:
        io = ServoIO(bus)
        silent = [j for j in joints if not await io.ping(j.id)]
        if silent:
            names = ", ".join(f"{j.name} (id {j.id})" for j in silent)
            term.say(f"Refused: no reply from {names}; run lupin check. Nothing was changed.")
            return EXIT_FAILED
        if not await release_torque(io, joints, term):
            return EXIT_FAILED
        try:
            old_offsets = await read_offsets(io, joints)
        except OffsetReadFailed as exc:
            term.say(f"Refused: {exc}. Nothing was changed.")
            return EXIT_FAILED

        rec = await phase_one(bus, joints, term)
        calibrations, refusals = plan(joints, rec, old_offsets, args.margin, homing)
        if refusals:
            for r in refusals:
                term.say(f"Refused: {r}")
            term.say("Nothing was written.")
            return EXIT_FAILED
        try:
            prepared = prepare(
                profile,
                calibrations,
                home=lupin_home(),
                profile_arg=args.profile,
                config_file=args.config,
                source="lupin calibrate" + (" --skip-homing" if not homing else ""),
            )
        except ConfigError as exc:
            term.say(f"Refused:\n{exc}\nNothing was written.")
            return EXIT_FAILED
        return await phase_two(io, prepared, profile, args, port, term)


async def phase_one(bus: ServoBus, joints: list[JointConfig], term: Terminal) -> SweepRecorder:
    rec = SweepRecorder.for_joints({j.name: j.id for j in joints})
    term.say(
        "Phase 1: move every joint to both of its mechanical stops, in any order.\n"
        "The table records each joint's range. Press Enter when every joint has been swept."
    )
    table = LiveTable(term.out, live=term.out.isatty())
    stop = asyncio.Event()

    async def wait_enter() -> None:
        await term.readline()
        stop.set()

    enter = asyncio.create_task(wait_enter(), name="calibrate-enter")
    try:
        await record_sweep(bus, rec, stop, on_sample=table.update)
    finally:
        enter.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await enter
    table.draw(rec)
    return rec


def plan(
    joints: list[JointConfig],
    rec: SweepRecorder,
    old_offsets: dict[str, int],
    margin: float,
    homing: bool,
) -> tuple[list[JointCalibration], list[CalibrationRefused]]:
    calibrations, refusals = [], []
    for j in joints:
        try:
            cal = plan_joint(j, rec.traces[j.name], old_offsets[j.name], margin, homing=homing)
        except CalibrationRefused as exc:
            refusals.append(exc)
        else:
            calibrations.append(cal)
    return calibrations, refusals


async def phase_two(
    io: ServoIO,
    prepared: PreparedCalibration,
    profile: RobotProfile,
    args: argparse.Namespace,
    port: str,
    term: Terminal,
) -> int:
    changes = prepared.changes
    if changes:
        term.say("\nPhase 2: centre the zeros. EEPROM writes (register 31, persistent):")
        for c in changes:
            term.say(f"  {c.describe()}")
        term.say(f"The current offsets are backed up to {prepared.backup_path} first.")
        if not await term.confirm("Write these offsets?"):
            term.say("Nothing was written; the ranges were not saved.")
            return EXIT_FAILED
    try:
        result = await commit(io, prepared, profile_name=profile.name, port=port)
    except asyncio.CancelledError:
        if changes:
            term.say(
                f"\nInterrupted during the EEPROM writes: some offsets may have changed. "
                f"Put them back with:\n  {restore_command(args)}"
            )
        raise
    except OffsetWriteFailed as exc:
        term.say(f"\nStopped: {exc}")
        if exc.changed:
            done = ", ".join(f"{c.name} (id {c.id})" for c in exc.changed)
            term.say(f"Already changed: {done}.")
        if exc.maybe_changed:
            term.say(f"{exc.failed.name} (id {exc.failed.id}) may or may not hold its new value.")
        term.say(
            f"arm.yaml and poses were not touched. Put the offsets back with:\n"
            f"  {restore_command(args)}"
        )
        return EXIT_FAILED
    if result.archived_backup is not None:
        term.say(f"(the previous backup was kept as {result.archived_backup})")
    for c in result.written:
        term.say(f"wrote and verified {c.describe()}")
    term.say(f"Saved the calibration to {prepared.overlay_path}.")
    if result.poses_migrated:
        term.say(
            f"Migrated the taught poses in {prepared.poses.path} by the computed shift "
            f"(previous file kept as {prepared.poses.path.name}.bak)."
        )
    for o in prepared.outside:
        term.say(
            f"Pose {o.pose!r} is now outside {o.joint}'s limits: {o.rad:+.3f} rad not in "
            f"[{o.lo:+.3f}, {o.hi:+.3f}]; re-teach it."
        )
    await warn_servo_limits(io, prepared.calibrations, term)
    return EXIT_OK
