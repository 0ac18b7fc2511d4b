"""Calibration phase 1: every joint's range, recorded while the operator sweeps them by hand.

The sweep may cross the encoder's 0/4095 boundary: the seed's two straddling
joints (shoulder_pan, wrist_roll) did. A plain min/max over raw counts would
then record nearly the whole circle, so each joint's stream is unwrapped: a jump
of more than half a revolution between two samples is a crossing, which no
hand-moved joint can produce at 20 Hz (bring-up seed). The recorded range is in
the frame of the first sample, and may run below 0 or above 4095.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

from lupin import control_table as ct
from lupin.bus import ServoBus
from lupin.joints import COUNTS_PER_REV, RAD_PER_COUNT

HALF_REV = COUNTS_PER_REV // 2
SAMPLE_HZ = 20.0
POSITION = ct.REGISTERS["present_position"]


@dataclass
class JointTrace:
    """One joint's unwrapped min/max so far."""

    name: str
    id: int
    samples: int = 0
    crossings: int = 0
    raw: int | None = None  # last raw reading, 0..4095
    now: int = 0  # last unwrapped reading
    lo: int = 0
    hi: int = 0

    def add(self, raw: int) -> None:
        raw %= COUNTS_PER_REV
        if self.raw is None:
            self.now = self.lo = self.hi = raw
        else:
            step = raw - self.raw
            if step > HALF_REV:
                step -= COUNTS_PER_REV
                self.crossings += 1
            elif step < -HALF_REV:
                step += COUNTS_PER_REV
                self.crossings += 1
            self.now += step
            self.lo = min(self.lo, self.now)
            self.hi = max(self.hi, self.now)
        self.raw = raw
        self.samples += 1

    @property
    def span(self) -> int:
        return self.hi - self.lo

    @property
    def span_rad(self) -> float:
        return self.span * RAD_PER_COUNT

    @property
    def wrapped(self) -> bool:
        """The swept range crosses the encoder's 0/4095 boundary in this frame."""
        return self.lo < 0 or self.hi >= COUNTS_PER_REV


@dataclass
class SweepRecorder:
    """The traces of all swept joints; pure, so the unwrapping is testable without a bus."""

    traces: dict[str, JointTrace]
    ticks: int = 0
    missed: dict[str, int] = field(default_factory=dict)

    @classmethod
    def for_joints(cls, joints: Mapping[str, int]) -> SweepRecorder:
        return cls({name: JointTrace(name, sid) for name, sid in joints.items()})

    def add(self, readings: Mapping[str, int | None]) -> None:
        self.ticks += 1
        for name, trace in self.traces.items():
            value = readings.get(name)
            if value is None:
                self.missed[name] = self.missed.get(name, 0) + 1
            else:
                trace.add(value)


async def record_sweep(
    bus: ServoBus,
    recorder: SweepRecorder,
    stop: asyncio.Event,
    *,
    hz: float = SAMPLE_HZ,
    on_sample: Callable[[SweepRecorder], None] | None = None,
) -> SweepRecorder:
    """Sample every joint's present position at ``hz`` with one SYNC_READ until ``stop``."""
    loop = asyncio.get_running_loop()
    ids: Sequence[int] = [t.id for t in recorder.traces.values()]
    names = {t.id: t.name for t in recorder.traces.values()}
    period = 1.0 / hz
    due = loop.time()
    while not stop.is_set():
        result = await bus.sync_read(ids, POSITION.address, POSITION.size)
        recorder.add(
            {names[sid]: ct.decode_value(POSITION, data) for sid, data in result.data.items()}
        )
        if on_sample is not None:
            on_sample(recorder)
        due = max(due + period, loop.time())
        try:
            async with asyncio.timeout(due - loop.time()):
                await stop.wait()
        except TimeoutError:
            pass
    return recorder
