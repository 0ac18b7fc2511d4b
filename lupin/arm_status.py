"""Closed-loop joint status and stall events, with a diagnosis an operator can act on.

Status comes from measured convergence, never from a request's acknowledgement
(the runbook: the service reply is True the instant the trajectory is
published; convergence is the only honest signal). A joint that never arrives is
how a silent servo reject or a shoulder_lift thermal trip shows up, so a stall
becomes an event naming the joint, the error and the likely cause:

* one joint far off while the others track: a servo trip (overload/overheat
  unload, or a latched servo), recoverable by heal or a power-cycle;
* several joints off at once: a control-level fault (bus, gate, controller).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from lupin.protocol import ServoError
from lupin.trajectory import JointStatus, JointTrajectoryInterpolator


@dataclass(frozen=True)
class StallEvent:
    t: float
    joint: str
    error_rad: float
    diagnosis: str


def diagnose(
    joint: str,
    stalled: set[str],
    tracking: set[str],
    error_bits: int,
) -> str:
    bits = ServoError(error_bits)
    causes = [b.name.lower() for b in ServoError if b in bits and b.name]
    flagged = f" (servo reports {', '.join(causes)})" if causes else ""
    if len(stalled) > 1 and len(stalled) >= len(tracking):
        return (
            f"{len(stalled)} joints off at once: a control fault (bus, command gate or "
            f"controller), not one servo{flagged}"
        )
    return (
        f"{joint} far off while the other joints track: likely a servo trip{flagged}; "
        "re-enable it with heal, or power-cycle it if it latched"
    )


class StallMonitor:
    """Watches the interpolator's statuses each tick and turns new stalls into events."""

    def __init__(
        self,
        traj: JointTrajectoryInterpolator,
        *,
        on_stall: Callable[[StallEvent], None] | None = None,
        keep: int = 50,
    ) -> None:
        self.traj = traj
        self.on_stall = on_stall
        self.events: deque[StallEvent] = deque(maxlen=keep)
        self._last: dict[str, JointStatus] = {}

    def update(
        self,
        now: float,
        measured: Mapping[str, float],
        error_bits: Mapping[str, int],
    ) -> list[StallEvent]:
        status = self.traj.status()
        stalled = {n for n, s in status.items() if s is JointStatus.STALLED}
        tracking = {n for n, s in status.items() if s in (JointStatus.MOVING, JointStatus.SETTLED)}
        new = []
        for name in sorted(stalled):
            if self._last.get(name) is JointStatus.STALLED:
                continue
            target = self.traj.target(name)
            pos = measured.get(name)
            err = abs(pos - target) if pos is not None and target is not None else math.nan
            event = StallEvent(
                now, name, err, diagnose(name, stalled, tracking, error_bits.get(name, 0))
            )
            self.events.append(event)
            new.append(event)
            if self.on_stall is not None:
                self.on_stall(event)
        self._last = status
        return new
