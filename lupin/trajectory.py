"""A joint_trajectory_controller-like interpolator for N named joints (radians).

Pure and clock-injected: every time-dependent call takes ``now`` (monotonic s).

* **Seeded first.** A joint has no setpoint until ``seed()`` gives it one (the
  runbook's startup pin: the commanded pose starts from the measured pose, so the
  first command never snaps the arm toward a stale or zero setpoint). ``sample()``
  leaves unseeded joints out.
* **Partial goals.** ``set_goal`` replaces only the joints its points name; the others
  keep doing what they were doing (``allow_partial_joints_goal``).
* **Continuous.** Each named joint's new motion starts from its *commanded* setpoint
  and commanded velocity at ``now`` (never from measurement, which lags during motion),
  so position and velocity are continuous when a goal replaces one mid-motion.
* **Cubic Hermite.** Between knots the path is a cubic Hermite spline. A point's
  velocity is used when given; otherwise the final point gets zero velocity and an
  interior point gets the central finite-difference slope, zero at a local extremum
  and limited to 3x the smaller neighbouring slope (Fritsch-Carlson), so the path never
  overshoots a waypoint. After the last point the joint holds its position with zero
  velocity (a non-zero final velocity, if given, ends there).
* **Supervision from convergence.** Status comes from measured positions, never from
  the request's ack (runbook: "Convergence is the only honest signal"): MOVING until
  the trajectory has ended and the joint is within ``goal_tolerance`` of its target
  (SETTLED), or STALLED when lag (commanded - measured) stays over ``stall_lag`` for
  ``stall_time`` (the bench tool's lag stop) or the joint is not settled by the end time
  plus ``settle_time_margin`` (how a silent servo reject or a thermal trip shows up).
  SETTLED and STALLED last until the next goal, seed or cancel; a stall does not stop
  the motion by itself, the owner decides (``cancel`` holds where the arm is).
"""

from __future__ import annotations

import bisect
import enum
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

Knot = tuple[float, float, float]  # (time s, position rad, velocity rad/s)


class JointStatus(enum.StrEnum):
    IDLE = "idle"  # no goal since the joint was seeded
    MOVING = "moving"
    SETTLED = "settled"
    STALLED = "stalled"


@dataclass(frozen=True)
class TrajectoryPoint:
    """Where the named joints must be ``time_from_start`` s after the goal is set."""

    positions: Mapping[str, float]
    time_from_start: float
    velocities: Mapping[str, float] | None = None


@dataclass
class _Joint:
    knots: list[Knot] = field(default_factory=list)  # [] unseeded, one knot = holding
    status: JointStatus = JointStatus.IDLE
    target: float | None = None
    end_time: float = -math.inf
    lag: float | None = None
    lag_since: float | None = None
    stall_reason: str | None = None


def _evaluate(knots: Sequence[Knot], t: float) -> tuple[float, float]:
    """Commanded (position, velocity) at ``t`` on a seeded joint's knots."""
    if len(knots) == 1 or t >= knots[-1][0]:
        return knots[-1][1], 0.0
    if t <= knots[0][0]:
        return knots[0][1], knots[0][2]
    i = bisect.bisect_right(knots, t, key=lambda k: k[0]) - 1
    (ta, pa, va), (tb, pb, vb) = knots[i], knots[i + 1]
    h = tb - ta
    s = (t - ta) / h
    s2, s3 = s * s, s * s * s
    pos = (
        (2 * s3 - 3 * s2 + 1) * pa
        + (s3 - 2 * s2 + s) * h * va
        + (-2 * s3 + 3 * s2) * pb
        + (s3 - s2) * h * vb
    )
    vel = (
        (6 * s2 - 6 * s) * pa
        + (3 * s2 - 4 * s + 1) * h * va
        + (-6 * s2 + 6 * s) * pb
        + (3 * s2 - 2 * s) * h * vb
    ) / h
    return pos, vel


def _interior_velocity(prev: Knot, here: Knot, nxt: Knot) -> float:
    d0 = (here[1] - prev[1]) / (here[0] - prev[0])
    d1 = (nxt[1] - here[1]) / (nxt[0] - here[0])
    if d0 * d1 <= 0:
        return 0.0  # a waypoint that is a turning point stays the extremum
    central = (nxt[1] - prev[1]) / (nxt[0] - prev[0])
    return math.copysign(min(abs(central), 3.0 * min(abs(d0), abs(d1))), central)


def _finite(value: float, what: str) -> float:
    if not math.isfinite(value):
        raise ValueError(f"{what} must be finite, got {value!r}")
    return float(value)


class JointTrajectoryInterpolator:
    def __init__(
        self,
        joints: Sequence[str],
        *,
        goal_tolerance: float = 0.02,
        stall_lag: float = 0.15,
        stall_time: float = 0.5,
        settle_time_margin: float = 1.0,
    ) -> None:
        if len(set(joints)) != len(joints):
            raise ValueError(f"duplicate joint names: {list(joints)}")
        for what, v, minimum in (
            ("goal_tolerance", goal_tolerance, 0.0),
            ("stall_lag", stall_lag, 0.0),
        ):
            if not math.isfinite(v) or v <= minimum:
                raise ValueError(f"{what} must be positive, got {v!r}")
        for what, v in (("stall_time", stall_time), ("settle_time_margin", settle_time_margin)):
            if not math.isfinite(v) or v < 0:
                raise ValueError(f"{what} must be >= 0, got {v!r}")
        self.goal_tolerance = goal_tolerance
        self.stall_lag = stall_lag
        self.stall_time = stall_time
        self.settle_time_margin = settle_time_margin
        self._joints = {name: _Joint() for name in joints}

    @property
    def joints(self) -> tuple[str, ...]:
        return tuple(self._joints)

    def _joint(self, name: str) -> _Joint:
        j = self._joints.get(name)
        if j is None:
            raise ValueError(f"unknown joint {name!r}; known: {list(self._joints)}")
        return j

    # -- commands -------------------------------------------------------------

    def seed(self, positions: Mapping[str, float]) -> None:
        """Pin the named joints' setpoints (rad), stopping any motion on them; status IDLE."""
        checked = {n: _finite(p, f"seed position of {n!r}") for n, p in positions.items()}
        for name in checked:
            self._joint(name)
        for name, pos in checked.items():
            self._joints[name] = _Joint(knots=[(-math.inf, pos, 0.0)], target=pos)

    def set_goal(self, points: Sequence[TrajectoryPoint], now: float) -> None:
        """Start a trajectory for the joints the points name, from their setpoint at ``now``."""
        _finite(now, "now")
        names = self._validate(points, now)
        for name in names:
            j = self._joints[name]
            pos, vel = _evaluate(j.knots, now)
            knots: list[Knot] = [(now, pos, vel)]
            knots += [
                (now + pt.time_from_start, float(pt.positions[name]), math.nan) for pt in points
            ]
            for i in range(1, len(knots)):
                given = points[i - 1].velocities
                if given is not None and name in given:
                    v = float(given[name])
                elif i == len(knots) - 1:
                    v = 0.0
                else:
                    v = _interior_velocity(knots[i - 1], knots[i], knots[i + 1])
                knots[i] = (knots[i][0], knots[i][1], v)
            j.knots = knots
            j.status, j.target, j.end_time = JointStatus.MOVING, knots[-1][1], knots[-1][0]
            j.lag_since = j.stall_reason = None

    def _validate(self, points: Sequence[TrajectoryPoint], now: float) -> list[str]:
        """Check the whole goal before touching any joint: a refused goal changes nothing."""
        if not points:
            raise ValueError("a trajectory needs at least one point")
        names = list(points[0].positions)
        if not names:
            raise ValueError("a trajectory point must name at least one joint")
        for name in names:
            if not self._joint(name).knots:
                raise ValueError(f"joint {name!r} is not seeded: seed it from measurement first")
        previous = 0.0
        for i, pt in enumerate(points):
            if set(pt.positions) != set(names):
                raise ValueError(
                    f"point {i} names {sorted(pt.positions)} but point 0 names {sorted(names)}"
                )
            t = _finite(pt.time_from_start, f"point {i} time_from_start")
            # Compared as absolute times too: far from the epoch two close offsets can
            # round to one instant, and a zero-length segment would divide by zero.
            if t <= previous or now + t <= now + previous:
                raise ValueError(
                    f"point {i}: time_from_start {t} must be greater than {previous}"
                    " (times strictly increase from the goal's start)"
                )
            previous = t
            for name, p in pt.positions.items():
                _finite(p, f"point {i} position of {name!r}")
            for name, v in (pt.velocities or {}).items():
                if name not in pt.positions:
                    raise ValueError(f"point {i} gives a velocity for {name!r} but no position")
                _finite(v, f"point {i} velocity of {name!r}")
        return names

    def cancel(
        self, measured: Mapping[str, float], now: float, joints: Iterable[str] | None = None
    ) -> None:
        """Stop the named (default: all) joints and hold their MEASURED position.

        A joint with no finite measurement holds its commanded setpoint at ``now``
        instead, and stays supervised if it was moving.
        """
        _finite(now, "now")
        names = list(self._joints) if joints is None else list(joints)
        for name in names:
            self._joint(name)
        for name in names:
            j = self._joints[name]
            pos = measured.get(name)
            if pos is not None and math.isfinite(pos):
                # Holding the measurement is converged by definition.
                settled = j.status is not JointStatus.IDLE
                j.status = JointStatus.SETTLED if settled else JointStatus.IDLE
            elif j.knots:
                pos = _evaluate(j.knots, now)[0]
            else:
                continue  # never seeded, never measured: nothing to hold
            j.knots, j.target, j.end_time = [(now, float(pos), 0.0)], float(pos), now
            j.lag_since = j.stall_reason = None

    # -- supervision ------------------------------------------------------------

    def update_measured(self, measured: Mapping[str, float], now: float) -> None:
        """Feed measured positions (rad). Unknown names and non-finite reads are skipped,
        so one state dict can feed several consumers and a glitched read is not a crash."""
        _finite(now, "now")
        for name, pos in measured.items():
            j = self._joints.get(name)
            if j is None or not math.isfinite(pos) or not j.knots:
                continue
            commanded = _evaluate(j.knots, now)[0]
            j.lag = abs(commanded - pos)
            if j.status is JointStatus.MOVING:
                self._supervise(j, pos, now)

    def _supervise(self, j: _Joint, pos: float, now: float) -> None:
        assert j.target is not None and j.lag is not None
        if now >= j.end_time and abs(pos - j.target) <= self.goal_tolerance:
            j.status, j.lag_since = JointStatus.SETTLED, None
            return
        if j.lag > self.stall_lag:
            if j.lag_since is None:
                j.lag_since = now
            if now - j.lag_since >= self.stall_time:
                j.status, j.stall_reason = JointStatus.STALLED, "lag"
                return
        else:
            j.lag_since = None
        if now > j.end_time + self.settle_time_margin:
            j.status, j.stall_reason = JointStatus.STALLED, "timeout"

    # -- queries ----------------------------------------------------------------

    def sample(self, now: float) -> dict[str, float]:
        """Commanded position (rad) of every seeded joint at ``now``."""
        return {n: _evaluate(j.knots, now)[0] for n, j in self._joints.items() if j.knots}

    def sample_velocity(self, now: float) -> dict[str, float]:
        """Commanded velocity (rad/s) of every seeded joint at ``now``."""
        return {n: _evaluate(j.knots, now)[1] for n, j in self._joints.items() if j.knots}

    def active(self, now: float) -> bool:
        """Whether any joint is mid-trajectory (its last point still ahead of ``now``)."""
        return any(len(j.knots) > 1 and now < j.knots[-1][0] for j in self._joints.values())

    def status(self) -> dict[str, JointStatus]:
        return {n: j.status for n, j in self._joints.items()}

    def lag(self, joint: str) -> float | None:
        """|commanded - measured| at the last measurement; None before one."""
        return self._joint(joint).lag

    def target(self, joint: str) -> float | None:
        """Final position of the joint's latest goal (or seed/hold); None if unseeded."""
        return self._joint(joint).target

    def end_time(self, joint: str) -> float | None:
        """When the joint's latest goal ends (monotonic s); None if it has none."""
        t = self._joint(joint).end_time
        return t if math.isfinite(t) else None

    def stall_reason(self, joint: str) -> str | None:
        """``"lag"`` or ``"timeout"`` while STALLED, else None."""
        j = self._joint(joint)
        return j.stall_reason if j.status is JointStatus.STALLED else None


__all__ = ["JointStatus", "JointTrajectoryInterpolator", "TrajectoryPoint"]
