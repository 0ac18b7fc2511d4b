"""After the daemon died: zero the wheels and limp every servo (``ExecStopPost``).

The daemon's own shutdown (SIGTERM) already does this (``ControlLoop.safe_stop``).
This helper covers the deaths that skip it: SIGKILL, the OOM killer, the
watchdog's SIGABRT on a stalled loop, a crash. Without it the arm keeps holding
its last goal with torque on (the shoulder_lift servo cooks against gravity, the
runbook's thermal trip) and a wheel in velocity mode keeps spinning.

Rules, each from a war story:

* one opener per bus: the bus is opened through the registry like any other
  opener, so it is refused, naming the PID, if anybody still holds the port; we
  never interleave packets with a live process (bring-up seed);
* a SYNC_WRITE is never answered, so each command goes out twice; limping a limp
  servo is harmless;
* never hang and never fail the unit's stop: one overall deadline, and every
  problem becomes a log line, not an exit status.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from lupin import control_table as ct
from lupin import registry
from lupin.bus import ServoBus
from lupin.config_models import RobotProfile

log = logging.getLogger(__name__)

GOAL_SPEED = ct.REGISTERS["goal_speed"]
TORQUE = ct.REGISTERS["torque_enable"]
ROUNDS = 2
ROUND_GAP_S = 0.02

Opener = Callable[..., Any]


@dataclass
class StopReport:
    """What the helper did, for the log and the tests."""

    action: str = "none"  # "limped", "skipped", "refused", "failed", "timeout"
    reason: str = ""
    wheel_ids: list[int] = field(default_factory=list)
    servo_ids: list[int] = field(default_factory=list)
    rounds: int = 0
    confirmed_off: list[int] = field(default_factory=list)
    still_on: list[int] = field(default_factory=list)
    silent: list[int] = field(default_factory=list)

    def summary(self) -> str:
        if self.action != "limped":
            return f"{self.action}: {self.reason}"
        text = (
            f"limped: goal speed 0 to wheels {self.wheel_ids}, torque off to servos "
            f"{self.servo_ids}, {self.rounds} rounds; read back off: {self.confirmed_off}"
        )
        if self.still_on:
            text += f"; STILL ON: {self.still_on}"
        if self.silent:
            text += f"; no answer: {self.silent}"
        return text


def clean_exit(env: Mapping[str, str]) -> bool:
    """True when systemd says the daemon exited by itself with status 0.

    systemd gives ExecStopPost ``$SERVICE_RESULT``, ``$EXIT_CODE`` and
    ``$EXIT_STATUS``. Only ``success`` + ``exited`` + ``0`` means the daemon ran
    its own safe stop; a death by signal is ``killed``/``dumped`` even when
    systemd counts SIGTERM as a success. Without those variables (run by hand)
    nothing is known, so the helper acts.
    """
    return (
        env.get("SERVICE_RESULT") == "success"
        and env.get("EXIT_CODE") == "exited"
        and env.get("EXIT_STATUS") == "0"
    )


def servo_ids(profile: RobotProfile) -> tuple[list[int], list[int]]:
    """(wheel ids, every servo id) of the profile."""
    wheels = [w.id for w in profile.base.wheels] if profile.base is not None else []
    arm = [j.id for j in profile.arm.joints]
    return wheels, arm + wheels


async def limp_all(
    profile: RobotProfile,
    port: str,
    *,
    opener: Opener | None = None,
    rounds: int = ROUNDS,
) -> StopReport:
    """Open the bus, zero the wheels and cut torque on every servo, ``rounds`` times.

    Raises whatever the opener raises (the port is held, missing, ...): the
    caller turns that into a report. Bound it with a timeout.
    """
    report = StopReport()
    report.wheel_ids, report.servo_ids = servo_ids(profile)
    open_link = opener or registry.load("lupin.bus", "serial")
    link = await open_link(port, profile.bus.baud)
    bus = ServoBus(link, reply_margin_s=profile.bus.reply_margin_s, retries=0)
    bus.start()
    try:
        zero = ct.encode_value(GOAL_SPEED, 0)
        for n in range(rounds):
            if n:
                await asyncio.sleep(ROUND_GAP_S)
            # Zero speed first, then torque off: a wheel re-energised later must
            # not pick up its old speed goal (the order of ControlLoop.safe_stop).
            await bus.sync_write(GOAL_SPEED.address, 2, dict.fromkeys(report.wheel_ids, zero))
            await bus.sync_write(TORQUE.address, 1, dict.fromkeys(report.servo_ids, b"\x00"))
            report.rounds += 1
        await _verify(bus, report)
    finally:
        await bus.close()
    report.action = "limped"
    return report


async def _verify(bus: ServoBus, report: StopReport) -> None:
    """Read torque back once: what the log says must be what the servos say."""
    result = await bus.sync_read(report.servo_ids, TORQUE.address, 1, retries=1)
    report.silent = list(result.missing)
    report.still_on = [sid for sid, data in result.data.items() if data[0]]
    report.confirmed_off = [sid for sid, data in result.data.items() if not data[0]]
    if report.still_on:
        # A servo that missed both broadcasts (noise on the line): ask it directly.
        for sid in report.still_on:
            await bus.write(sid, TORQUE.address, b"\x00")
        again = await bus.sync_read(report.still_on, TORQUE.address, 1)
        fixed = [sid for sid, data in again.data.items() if not data[0]]
        report.confirmed_off += fixed
        report.still_on = [sid for sid in report.still_on if sid not in fixed]


async def run_stop_helper(
    profile: RobotProfile,
    port: str,
    *,
    env: Mapping[str, str],
    timeout: float,
    opener: Opener | None = None,
) -> StopReport:
    """The whole helper: skip after a clean exit, else limp within ``timeout``; never raises."""
    if clean_exit(env):
        return StopReport("skipped", "the daemon exited cleanly and limped the robot itself")
    try:
        async with asyncio.timeout(timeout):
            return await limp_all(profile, port, opener=opener)
    except TimeoutError:
        return StopReport("timeout", f"gave up after {timeout:.1f} s on {port}")
    except Exception as exc:
        # The serial adapter's PortBusy names the PID that owns the bus now. The
        # core never imports an adapter (STYLE), so it is recognised by name.
        kind = "refused" if type(exc).__name__ == "PortBusy" else "failed"
        return StopReport(kind, f"{port}: {exc}")


def describe_exit(env: Mapping[str, str]) -> str:
    """How systemd says the daemon ended, for the log line."""
    keys = ("SERVICE_RESULT", "EXIT_CODE", "EXIT_STATUS")
    if not any(k in env for k in keys):
        return "run by hand"
    return ", ".join(f"{k}={env.get(k, '?')}" for k in keys)


__all__ = ["StopReport", "clean_exit", "describe_exit", "limp_all", "run_stop_helper", "servo_ids"]
