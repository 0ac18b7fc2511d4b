"""What every bench command shares at the terminal: prompts, Enter, exit codes, the bus.

Prompts and Enter are read from stdin inside the event loop (``add_reader``),
never in a thread: a thread blocked on ``readline`` would keep a Ctrl-C'd tool
alive until someone pressed Enter, and the sweep's cleanup must run at once.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
from collections.abc import Awaitable, Callable, Sequence
from typing import TextIO

from lupin.bench.homing import JointCalibration
from lupin.bench.registers import ServoIO
from lupin.bench.session import BusOpenFailed
from lupin.bus import BusClosed
from lupin.config import load_profile
from lupin.config_models import JointConfig, RobotProfile

EXIT_OK = 0
EXIT_FAILED = 1  # refused, or a servo did not do what it was told
EXIT_USAGE = 2
EXIT_BUS = 4  # the bus could not be opened: nothing was sent (as ``lupin run``)


class UsageError(Exception):
    """A bad argument found after parsing (an unknown joint name); exit 2."""


class Terminal:
    """Questions and answers on stdin/stdout; ``yes`` answers every question for scripts."""

    def __init__(self, yes: bool, stdin: TextIO | None = None, out: TextIO | None = None) -> None:
        self.yes = yes
        self.stdin = stdin or sys.stdin
        self.out = out or sys.stdout
        self._buffer = b""
        self._eof = False

    def say(self, text: str = "") -> None:
        print("\n".join(line.rstrip() for line in text.split("\n")), file=self.out, flush=True)

    async def confirm(self, question: str) -> bool:
        """Ask a yes/no question; anything but y/yes (or end of input) is no."""
        if self.yes:
            self.say(f"{question} [y/N] yes (--yes)")
            return True
        print(f"{question} [y/N] ", end="", file=self.out, flush=True)
        line = await self.readline()
        if line is None:
            self.say("\nno answer (end of input): taken as no")
            return False
        return line.strip().lower() in ("y", "yes")

    async def readline(self) -> str | None:
        """One line from stdin, or None at end of input."""
        while b"\n" not in self._buffer and not self._eof:
            await self._fill()
        if b"\n" in self._buffer:
            line, self._buffer = self._buffer.split(b"\n", 1)
            return line.decode(errors="replace")
        if self._buffer:
            line, self._buffer = self._buffer, b""
            return line.decode(errors="replace")
        return None

    async def _fill(self) -> None:
        try:
            fd = self.stdin.fileno()
        except (AttributeError, OSError, ValueError):
            self._eof = True
            return
        loop = asyncio.get_running_loop()
        ready: asyncio.Future[None] = loop.create_future()

        def on_readable() -> None:
            if not ready.done():
                ready.set_result(None)

        try:
            loop.add_reader(fd, on_readable)
        except (PermissionError, OSError, ValueError):
            # A regular file cannot be polled, and never blocks: just read it.
            self._take(os.read(fd, 4096))
            return
        try:
            await ready
        finally:
            loop.remove_reader(fd)
        self._take(os.read(fd, 4096))

    def _take(self, data: bytes) -> None:
        if data:
            self._buffer += data
        else:
            self._eof = True


async def release_torque(io: ServoIO, joints: list[JointConfig], term: Terminal) -> bool:
    """Limp every swept joint; ask first only if one is actually torqued (register read)."""
    states = {j.name: await io.read(j.id, "torque_enable") for j in joints}
    unknown = [n for n, v in states.items() if v is None]
    if unknown:
        term.say(f"Refused: cannot read torque_enable from {', '.join(unknown)}.")
        return False
    torqued = [j for j in joints if states[j.name]]
    if not torqued:
        return True
    names = ", ".join(j.name for j in torqued)
    term.say(f"Torque is on for {names}. Releasing it lets the arm fall: support it first.")
    if not await term.confirm("Release torque now?"):
        term.say("Nothing was changed.")
        return False
    for j in torqued:
        if not await io.set_torque(j.id, False) or await io.read(j.id, "torque_enable") != 0:
            term.say(f"Refused: {j.name} (id {j.id}) did not release torque.")
            return False
    term.say(f"Torque released on {names}.")
    return True


async def warn_servo_limits(
    io: ServoIO, calibrations: Sequence[JointCalibration], term: Terminal
) -> None:
    """Say so when the servo's own limit registers would stop it short of the new band."""
    for c in calibrations:
        regs = await io.read_many(c.id, ("min_position_limit", "max_position_limit"))
        if regs is None:
            continue
        lo, hi = regs["min_position_limit"], regs["max_position_limit"]
        if (lo or hi) and (c.min < lo or c.max > hi):
            term.say(
                f"Note: {c.name}'s servo limit registers {lo}..{hi} are narrower than its new "
                f"band {c.min}..{c.max}; the servo will stop there (lupin leaves them alone)."
            )


def load(args: argparse.Namespace) -> RobotProfile:
    return load_profile(args.profile, config_file=args.config)


def port_of(args: argparse.Namespace, profile: RobotProfile) -> str:
    return str(args.bus_port or profile.bus.port)


def select_joints(profile: RobotProfile, text: str | None) -> list[JointConfig]:
    """The arm joints named in a comma-separated list (all when None), in profile order."""
    if text is None:
        return list(profile.arm.joints)
    wanted = [n.strip() for n in text.split(",") if n.strip()]
    names = [j.name for j in profile.arm.joints]
    unknown = [n for n in wanted if n not in names]
    if unknown or not wanted:
        raise UsageError(f"unknown joints {unknown or text!r}; this arm has {', '.join(names)}")
    return [j for j in profile.arm.joints if j.name in wanted]


def restore_command(args: argparse.Namespace) -> str:
    """The exact recovery command for this bus and profile."""
    parts = ["lupin offsets restore"]
    for flag, value in (
        ("--profile", args.profile),
        ("--config", args.config),
        ("--bus-port", args.bus_port),
    ):
        if value:
            parts += [flag, str(value)]
    return " ".join(parts)


def run_tool(command: str, body: Callable[[], Awaitable[int]]) -> int:
    """Run an async tool body; a bus that cannot be opened or a bad joint name is reported."""

    async def guarded() -> int:
        try:
            return await body()
        except BusOpenFailed as exc:
            print(f"lupin {command}: {exc}", file=sys.stderr, flush=True)
            return EXIT_BUS
        except UsageError as exc:
            print(f"lupin {command}: {exc}", file=sys.stderr, flush=True)
            return EXIT_USAGE
        except (ConnectionError, BusClosed) as exc:  # unplugged mid-run
            print(f"lupin {command}: lost the servo bus: {exc}", file=sys.stderr, flush=True)
            return EXIT_FAILED

    return asyncio.run(guarded())
