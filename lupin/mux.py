"""Velocity arbitration: twist_mux's priority-with-timeout mux, and what every mux shares.

Several producers (the pad's dead-man teleop, the web HMI, an autonomy stack, the
sim idle-stop) submit twists; the mux forwards exactly one. Muxes are pure (the
2-source takeover mux is in :mod:`lupin.takeover_mux`):
every call takes ``now`` (monotonic seconds) and nothing here sleeps or does I/O.

Priority mux rules (``VelocityMux``), copied from twist_mux:

* A source is *fresh* while ``now - last_submit <= timeout``; timeout 0 never expires.
* A lock is *engaged* while its latest value is True and it is fresh (timeout 0 never
  expires). Note: twist_mux also engages a lock whose publisher has gone stale; Lupin
  does not, a lock needs an explicit True.
* The highest engaged lock of priority L masks every source with priority < L
  (twist_mux's ``isMasked``: a source of priority equal to L still passes).
* Among fresh, unmasked sources the highest priority wins; equal priorities go to
  the one that submitted most recently, then to declaration order.
* With no winner the mux outputs *nothing* (``twist is None``), never a zero: the
  base's own command timeout stops the wheels, as on the real robot.

The E-stop is a lock named ``VelocityMux.estop_lock_name`` that the daemon declares
above every source (priority 256 > the configurable 0-255) with timeout 0, so it masks
all of them: the output is nothing with ``locked_by="estop"``; the daemon zeroes the
wheels itself.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import ClassVar, Protocol


@dataclass(frozen=True)
class Twist:
    """A planar velocity command: m/s forward, m/s left, rad/s counter-clockwise."""

    linear_x: float = 0.0
    linear_y: float = 0.0
    angular_z: float = 0.0

    def is_zero(self) -> bool:
        return self.linear_x == 0.0 and self.linear_y == 0.0 and self.angular_z == 0.0

    def is_finite(self) -> bool:
        return all(math.isfinite(v) for v in (self.linear_x, self.linear_y, self.angular_z))


ZERO_TWIST = Twist()


def _check_spec(kind: str, name: str, priority: int, timeout: float) -> None:
    if not name:
        raise ValueError(f"a mux {kind} needs a name")
    if isinstance(priority, bool) or not isinstance(priority, int):
        raise ValueError(f"mux {kind} {name!r}: priority must be an int, got {priority!r}")
    if not math.isfinite(timeout) or timeout < 0:
        raise ValueError(f"mux {kind} {name!r}: timeout must be >= 0 s, got {timeout!r}")


@dataclass(frozen=True)
class SourceSpec:
    """A twist input: higher priority wins; ``timeout`` 0 means it never expires."""

    name: str
    priority: int
    timeout: float

    def __post_init__(self) -> None:
        _check_spec("source", self.name, self.priority, self.timeout)


@dataclass(frozen=True)
class LockSpec:
    """A boolean input that, while engaged, masks every source of lower priority."""

    name: str
    priority: int
    timeout: float

    def __post_init__(self) -> None:
        _check_spec("lock", self.name, self.priority, self.timeout)


@dataclass(frozen=True)
class MuxOutput:
    """One tick's decision. ``twist is None`` means send nothing at all.

    Nothing active: ``source is None and locked_by is None``. Locked (E-stop):
    ``locked_by`` names the highest engaged lock, whether or not a source above it wins.
    """

    source: str | None
    twist: Twist | None
    locked_by: str | None = None

    @property
    def active(self) -> bool:
        return self.twist is not None


@dataclass(frozen=True)
class SourceState:
    priority: int
    timeout: float
    age: float | None  # seconds since the last accepted twist; None = never
    fresh: bool
    masked: bool  # fresh but not allowed through (a lock, or the takeover window)


@dataclass(frozen=True)
class LockState:
    priority: int
    timeout: float
    value: bool | None  # latest value; None = never set
    age: float | None
    engaged: bool


@dataclass(frozen=True)
class MuxStatus:
    """Per-source freshness and lock states, for the API and /metrics."""

    active: str | None
    locked_by: str | None
    sources: dict[str, SourceState]
    locks: dict[str, LockState]

    def to_dict(self) -> dict[str, object]:
        return asdict(self)


class Mux(Protocol):
    """What the daemon needs from either mux, so the two can be swapped by config."""

    def submit(self, source: str, twist: Twist, now: float) -> None: ...
    def output(self, now: float) -> MuxOutput: ...
    def status(self, now: float) -> MuxStatus: ...
    def last_seen(self, source: str) -> float: ...


def is_fresh(stamp: float | None, timeout: float, now: float) -> bool:
    # twist_mux's hasExpired() is `age > timeout`, so the exact boundary is still fresh.
    return stamp is not None and (timeout == 0 or now - stamp <= timeout)


def check_submit(twist: Twist, now: float) -> None:
    if not twist.is_finite():
        raise ValueError(f"twist has a non-finite component: {twist}")
    if not math.isfinite(now):
        raise ValueError(f"now must be finite, got {now!r}")


class VelocityMux:
    """twist_mux: the highest-priority fresh source wins, locks mask lower priorities."""

    estop_lock_name: ClassVar[str] = "estop"

    def __init__(self, sources: Sequence[SourceSpec], locks: Sequence[LockSpec] = ()) -> None:
        if not sources:
            raise ValueError("a velocity mux needs at least one source")
        names = [s.name for s in sources] + [lk.name for lk in locks]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise ValueError(f"duplicate mux source/lock names: {dupes}")
        self._sources = {s.name: s for s in sources}  # dicts keep declaration order
        self._locks = {lk.name: lk for lk in locks}
        self._twists: dict[str, tuple[Twist, float]] = {}
        self._lock_values: dict[str, tuple[bool, float]] = {}

    @property
    def sources(self) -> tuple[SourceSpec, ...]:
        return tuple(self._sources.values())

    @property
    def locks(self) -> tuple[LockSpec, ...]:
        return tuple(self._locks.values())

    def submit(self, source: str, twist: Twist, now: float) -> None:
        """Record ``twist`` from ``source`` at ``now``; the caller validates limits."""
        spec = self._sources.get(source)
        if spec is None:
            raise KeyError(f"unknown mux source {source!r}; known: {sorted(self._sources)}")
        check_submit(twist, now)
        lock = self._highest_lock(now)
        if lock is not None and spec.priority < lock.priority:
            # twist_mux zeroes a message that arrives while masked: the source stays
            # fresh, but releasing the lock (the E-stop) never replays a command
            # issued under it; motion resumes only with the next submission.
            twist = ZERO_TWIST
        self._twists[source] = (twist, now)

    def set_lock(self, name: str, engaged: bool, now: float) -> None:
        if name not in self._locks:
            raise KeyError(f"unknown mux lock {name!r}; known: {sorted(self._locks)}")
        if not math.isfinite(now):
            raise ValueError(f"now must be finite, got {now!r}")
        self._lock_values[name] = (bool(engaged), now)

    def last_seen(self, source: str) -> float:
        """When ``source`` last submitted (monotonic s); -inf if never."""
        if source not in self._sources:
            raise KeyError(f"unknown mux source {source!r}; known: {sorted(self._sources)}")
        entry = self._twists.get(source)
        return entry[1] if entry is not None else -math.inf

    def _engaged(self, spec: LockSpec, now: float) -> bool:
        entry = self._lock_values.get(spec.name)
        return entry is not None and entry[0] and is_fresh(entry[1], spec.timeout, now)

    def _highest_lock(self, now: float) -> LockSpec | None:
        best: LockSpec | None = None
        for spec in self._locks.values():  # strict > keeps the first declared on ties
            if self._engaged(spec, now) and (best is None or spec.priority > best.priority):
                best = spec
        return best

    def _source_fresh(self, spec: SourceSpec, now: float) -> bool:
        entry = self._twists.get(spec.name)
        return is_fresh(entry[1] if entry else None, spec.timeout, now)

    def output(self, now: float) -> MuxOutput:
        lock = self._highest_lock(now)
        floor = lock.priority if lock is not None else None
        locked_by = lock.name if lock is not None else None
        best: tuple[int, float, int] | None = None
        winner: str | None = None
        for index, spec in enumerate(self._sources.values()):
            if not self._source_fresh(spec, now):
                continue
            if floor is not None and spec.priority < floor:
                continue
            # Ties: the most recent submission, then the earlier declaration (-index).
            key = (spec.priority, self._twists[spec.name][1], -index)
            if best is None or key > best:
                best, winner = key, spec.name
        if winner is None:
            return MuxOutput(None, None, locked_by)
        return MuxOutput(winner, self._twists[winner][0], locked_by)

    def status(self, now: float) -> MuxStatus:
        out = self.output(now)
        sources: dict[str, SourceState] = {}
        for spec in self._sources.values():
            entry = self._twists.get(spec.name)
            fresh = self._source_fresh(spec, now)
            masked = (
                fresh
                and out.locked_by is not None
                and (spec.priority < self._locks[out.locked_by].priority)
            )
            age = now - entry[1] if entry else None
            sources[spec.name] = SourceState(spec.priority, spec.timeout, age, fresh, masked)
        locks: dict[str, LockState] = {}
        for lk in self._locks.values():
            value = self._lock_values.get(lk.name)
            locks[lk.name] = LockState(
                lk.priority,
                lk.timeout,
                value[0] if value else None,
                now - value[1] if value else None,
                self._engaged(lk, now),
            )
        return MuxStatus(out.source, out.locked_by, sources, locks)


__all__ = [
    "ZERO_TWIST",
    "LockSpec",
    "LockState",
    "Mux",
    "MuxOutput",
    "MuxStatus",
    "SourceSpec",
    "SourceState",
    "Twist",
    "VelocityMux",
    "check_submit",
    "is_fresh",
]
