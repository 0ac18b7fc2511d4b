"""The 2-source takeover mux (the runbook's cmd_vel_mux variant): manual wins for a window.

An alternative to :class:`lupin.mux.VelocityMux`, chosen by the profile's
``mux.mode``. Pure, as every mux: each call takes ``now`` and nothing here does I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import ClassVar

from lupin.mux import (
    MuxOutput,
    MuxStatus,
    SourceSpec,
    SourceState,
    Twist,
    check_submit,
    is_fresh,
)


class TakeoverMux:
    """The 2-source cmd_vel_mux: ``manual`` passes straight through, and ``auto`` is
    dropped for ``manual_takeover_seconds`` after each manual twist, giving the operator
    a takeover window without fighting the autonomy stack (runbook, "The 2-source
    variant"). It has no locks: the daemon handles the E-stop itself in this mode.

    The output is the most recently forwarded twist while its source is fresh (each
    source's own timeout), else nothing; an older twist is never replayed.
    """

    MANUAL: ClassVar[str] = "manual"
    AUTO: ClassVar[str] = "auto"

    def __init__(
        self, sources: Sequence[SourceSpec], *, manual_takeover_seconds: float = 0.5
    ) -> None:
        names = [s.name for s in sources]
        want = [self.MANUAL, self.AUTO]
        if sorted(names) != sorted(want):
            raise ValueError(f"the takeover mux takes exactly the sources {want}, got {names}")
        if not math.isfinite(manual_takeover_seconds) or manual_takeover_seconds < 0:
            raise ValueError(f"manual_takeover_seconds must be >= 0, got {manual_takeover_seconds}")
        self._sources = {s.name: s for s in sources}
        self.manual_takeover_seconds = manual_takeover_seconds
        self._last: dict[str, tuple[Twist, float]] = {}
        self._forwarded: str | None = None
        self.dropped = 0  # auto twists dropped inside a takeover window

    @property
    def sources(self) -> tuple[SourceSpec, ...]:
        return tuple(self._sources.values())

    def _in_takeover(self, now: float) -> bool:
        manual = self._last.get(self.MANUAL)
        window = self.manual_takeover_seconds
        # `<=` matches freshness: with the defaults (window = manual timeout = 0.5 s)
        # auto is let through exactly when manual's last twist expires.
        return manual is not None and window > 0 and now - manual[1] <= window

    def submit(self, source: str, twist: Twist, now: float) -> None:
        if source not in self._sources:
            raise KeyError(f"unknown mux source {source!r}; known: {sorted(self._sources)}")
        check_submit(twist, now)
        if source == self.AUTO and self._in_takeover(now):
            self.dropped += 1
            return
        self._last[source] = (twist, now)
        self._forwarded = source

    def last_seen(self, source: str) -> float:
        """When ``source``'s last *accepted* twist arrived (monotonic s); -inf if never."""
        if source not in self._sources:
            raise KeyError(f"unknown mux source {source!r}; known: {sorted(self._sources)}")
        entry = self._last.get(source)
        return entry[1] if entry is not None else -math.inf

    def output(self, now: float) -> MuxOutput:
        name = self._forwarded
        if name is None:
            return MuxOutput(None, None)
        twist, stamp = self._last[name]
        if not is_fresh(stamp, self._sources[name].timeout, now):
            return MuxOutput(None, None)
        return MuxOutput(name, twist)

    def status(self, now: float) -> MuxStatus:
        out = self.output(now)
        sources: dict[str, SourceState] = {}
        for spec in self._sources.values():
            entry = self._last.get(spec.name)
            fresh = is_fresh(entry[1] if entry else None, spec.timeout, now)
            masked = spec.name == self.AUTO and fresh and out.source == self.MANUAL
            age = now - entry[1] if entry else None
            sources[spec.name] = SourceState(spec.priority, spec.timeout, age, fresh, masked)
        return MuxStatus(out.source, None, sources, {})
