"""The arm commander: the one authoritative commanded pose, and the gates in front of it.

Three mechanisms from the runbook's "open-loop re-assert war" live here, because
a stale setpoint is what snaps an arm back:

* startup pin: the commanded pose is seeded from the first complete measurement,
  and nothing is sent before;
* resync: a joint that measurement shows more than the threshold (0.08 rad) from
  its command while no motion is commanded on it is re-adopted from measurement,
  so whichever surface moved it last wins instead of being yanked back;
* torque enable re-pins the command to the measured pose before energising.

Every goal is clamped to the joint window here, at the bus boundary, for every
client. This module is pure: time is passed in.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from lupin.joints import JointGeometry
from lupin.trajectory import JointStatus, JointTrajectoryInterpolator, TrajectoryPoint


class Torque(enum.StrEnum):
    UNKNOWN = "unknown"
    OFF = "off"
    ENABLING = "enabling"
    ON = "on"


class Refused(Exception):
    """A motion request was refused; the message says why, for the operator."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class MoveResult:
    targets: dict[str, float]  # clamped final positions, rad
    duration: float


class ArmCommander:
    def __init__(
        self,
        joints: Mapping[str, JointGeometry],
        *,
        resync_threshold: float = 0.08,
        goal_tolerance: float = 0.03,
    ) -> None:
        self.joints = dict(joints)
        self.names = list(joints)
        self.resync_threshold = resync_threshold
        self.traj = JointTrajectoryInterpolator(self.names, goal_tolerance=goal_tolerance)
        self.measured: dict[str, float] = {}
        self.commanded: dict[str, float] | None = None
        self.torque: dict[str, Torque] = dict.fromkeys(self.names, Torque.UNKNOWN)
        self.excluded: dict[str, str] = {}
        self.estop = False
        self.gate_open = False
        self.resyncs = 0
        # Joints whose last motion stalled; shown as stalled until next commanded.
        self.stalled: set[str] = set()

    # -- measurement -----------------------------------------------------------

    @property
    def seeded(self) -> bool:
        return self.commanded is not None

    def observe(self, measured: Mapping[str, float], now: float) -> None:
        """Feed this tick's measured positions (rad) of the joints that answered."""
        self.measured.update(measured)
        if self.commanded is None:
            if all(n in self.measured for n in self.names):
                self.commanded = dict(self.measured)
                self.traj.seed(self.commanded)  # the startup pin
            return
        self.traj.update_measured(measured, now)
        for name, pos in measured.items():
            if self.traj_active(name, now):
                continue
            if abs(pos - self.commanded[name]) > self.resync_threshold:
                self._adopt(name, pos)

    def traj_active(self, name: str, now: float) -> bool:
        # A stalled joint still has motion commanded on it: resync must not hide the stall.
        return self.traj.status().get(name) in (JointStatus.MOVING, JointStatus.STALLED)

    def _adopt(self, name: str, pos: float) -> None:
        assert self.commanded is not None
        self.commanded[name] = pos
        self.traj.seed({name: pos})
        self.resyncs += 1

    def set_torque_state(self, name: str, state: Torque) -> None:
        self.torque[name] = state

    @property
    def torque_summary(self) -> Torque:
        states = {s for n, s in self.torque.items() if n not in self.excluded}
        return states.pop() if len(states) == 1 else Torque.UNKNOWN

    # -- commands ---------------------------------------------------------------

    def check_can_move(self, names: Sequence[str]) -> None:
        if self.estop:
            raise Refused("estop", "the E-stop is engaged")
        if self.commanded is None:
            raise Refused("not_seeded", "joint not seeded: no complete joint state yet")
        for name in names:
            if name not in self.joints:
                raise Refused("unknown_joint", f"unknown joint {name!r}")
            if name in self.excluded:
                raise Refused("excluded", f"{name} is excluded: {self.excluded[name]}")
            if self.torque[name] is not Torque.ON or not self.gate_open:
                raise Refused("torque_off", f"torque is {self.torque[name].value} on {name}")

    def move(self, targets: Mapping[str, float], duration: float, now: float) -> MoveResult:
        """Move the named joints to ``targets`` (rad) in ``duration`` s; others keep going."""
        self.check_can_move(list(targets))
        if not math.isfinite(duration) or duration <= 0:
            raise Refused("bad_duration", f"travel time must be positive, got {duration}")
        clamped = {n: self.joints[n].clamp_rad(v) for n, v in targets.items()}
        self.stalled.difference_update(clamped)
        self.traj.set_goal([TrajectoryPoint(positions=clamped, time_from_start=duration)], now)
        assert self.commanded is not None
        self.commanded.update(clamped)
        return MoveResult(clamped, duration)

    def stream(self, points: Sequence[TrajectoryPoint], now: float) -> None:
        names = sorted({n for p in points for n in p.positions})
        self.check_can_move(names)
        clamped = [
            TrajectoryPoint(
                positions={n: self.joints[n].clamp_rad(v) for n, v in p.positions.items()},
                time_from_start=p.time_from_start,
                velocities=p.velocities,
            )
            for p in points
        ]
        self.stalled.difference_update(names)
        self.traj.set_goal(clamped, now)
        assert self.commanded is not None
        self.commanded.update(clamped[-1].positions)

    def hold(self, now: float) -> None:
        """Stop every joint where it is measured to be (E-stop, cancel)."""
        if self.commanded is None:
            return
        held = {n: self.measured[n] for n in self.names if n in self.measured}
        self.traj.cancel(held, now)
        self.commanded.update(held)

    def pin_to_measured(self, names: Sequence[str]) -> None:
        """Re-pin the command of ``names`` to their measured pose (before energising)."""
        if self.commanded is None:
            return
        for name in names:
            if name in self.measured:
                self.commanded[name] = self.measured[name]
                self.traj.seed({name: self.measured[name]})

    # -- output to the bus ----------------------------------------------------------

    def goals(self, now: float) -> dict[str, float]:
        """Clamped setpoints (rad) for the joints that may be driven now; empty if none."""
        # The E-stop does not stop the goals: it holds them at the measured pose (hold()).
        if self.commanded is None or not self.gate_open:
            return {}
        sample = self.traj.sample(now)
        out = {}
        for name in self.names:
            if self.torque[name] is Torque.ON and name not in self.excluded:
                out[name] = self.joints[name].clamp_rad(sample.get(name, self.commanded[name]))
        return out
