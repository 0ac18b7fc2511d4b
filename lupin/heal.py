"""Boot heal and auto-home, and the re-heal after a suspend/resume.

Heal answers a tri-state, and the third state is the one that matters: when the
bus cannot be enumerated at all, the answer is ``unknown`` and nothing is
attempted or retried, because acting without knowing is guessing, and retrying
on failure is the runbook's 2026-05-27 retry storm. ``healed`` means something
was fixed without guessing (a servo that unloaded after an overload re-enabled
against its present position, a crashed task restarted); ``failed`` names what
could not be fixed (a missing servo, a wrong operating mode: never blind-written).

Auto-home then waits up to 30 s for full joint state, settles 2 s and parks the
arm at ``home``, the minimum-gravity pose that keeps the shoulder from cooking.
"""

from __future__ import annotations

import asyncio
import logging
import os
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Literal, Protocol

from lupin import control_table as ct
from lupin.protocol import ServoError

log = logging.getLogger(__name__)

HealResult = Literal["healthy", "healed", "failed", "unknown"]
AutoHomeState = Literal["done", "skipped", "disabled", "failed", "pending"]
TRIP_BITS = ServoError.OVERLOAD | ServoError.OVERHEAT | ServoError.OVERCURRENT
STATE_ADDR = ct.REGISTERS["operating_mode"].address  # 33 .. 40: mode .. torque_enable
STATE_LEN = ct.REGISTERS["torque_enable"].address - STATE_ADDR + 1


@dataclass
class HealReport:
    result: HealResult
    details: list[str] = field(default_factory=list)


class HealTarget(Protocol):
    """What heal needs from the daemon (kept narrow so it can be tested alone)."""

    async def enumerate(self) -> dict[int, tuple[int, int, int]] | None:
        """id -> (operating mode, torque enable, status error byte); None if the bus is down."""
        ...

    def expected(self) -> dict[int, tuple[str, int, bool]]:
        """id -> (name, expected mode, torque wanted on)."""
        ...

    async def reenable(self, servo_id: int) -> bool: ...

    def dead_tasks(self) -> list[str]: ...

    async def restart_tasks(self) -> list[str]: ...


async def heal(target: HealTarget) -> HealReport:
    found = await target.enumerate()
    if not found:
        return HealReport("unknown", ["the bus could not be enumerated: no servo answered"])
    details: list[str] = []
    fixed = failed = False
    for sid, (name, mode, want_torque) in sorted(target.expected().items()):
        got = found.get(sid)
        if got is None:
            details.append(f"{name} (id {sid}) does not answer")
            failed = True
            continue
        got_mode, torque, error = got
        if got_mode != mode:
            details.append(f"{name} (id {sid}) is in mode {got_mode}, expected {mode}: excluded")
            failed = True
            continue
        if want_torque and not torque:
            why = ", ".join(b.name.lower() for b in ServoError if b in ServoError(error) and b.name)
            if await target.reenable(sid):
                details.append(f"{name} (id {sid}) had unloaded ({why or 'no flag'}): re-enabled")
                fixed = True
            else:
                details.append(f"{name} (id {sid}) unloaded and did not re-enable (latched?)")
                failed = True
    for task in await target.restart_tasks():
        details.append(f"restarted the crashed {task} task")
        fixed = True
    if failed:
        return HealReport("failed", details)
    return HealReport("healed" if fixed else "healthy", details or ["every servo answers"])


def auto_home_enabled() -> bool:
    return os.environ.get("LUPIN_AUTO_HOME", "true").strip().lower() not in ("0", "false", "no")


async def auto_home(
    wait_seeded: Callable[[float], Awaitable[bool]],
    park: Callable[[], Awaitable[None]],
    *,
    wait_s: float = 30.0,
    settle_s: float = 2.0,
) -> AutoHomeState:
    """Wait for full joint state, settle, park at home. Returns done/failed."""
    if not await wait_seeded(wait_s):
        log.warning("auto-home: no full joint state within %.0f s; not parking", wait_s)
        return "failed"
    await asyncio.sleep(settle_s)
    try:
        await park()
    except Exception as exc:
        log.warning("auto-home: could not park at home: %s", exc)
        return "failed"
    log.info("auto-home: parking at home")
    return "done"


class ResumeWatcher:
    """Notices a suspend/resume: boot time jumps ahead of monotonic time.

    systemd boot units do not re-fire on resume (the runbook), so the daemon
    re-heals by itself when the two clocks drift apart by more than ``jump``.
    """

    def __init__(self, jump: float = 2.0) -> None:
        self.jump = jump
        self._offset = self._read()

    @staticmethod
    def _read() -> float:
        return time.clock_gettime(time.CLOCK_BOOTTIME) - time.monotonic()

    def resumed(self) -> bool:
        offset = self._read()
        jumped = offset - self._offset > self.jump
        self._offset = offset
        return jumped
