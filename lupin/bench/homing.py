"""Calibration phase 2's arithmetic: offsets, bands and the refusals, with no I/O.

The servo reports ``present = (actual - offset) mod 4096`` (register 31, ±2047),
so writing a new offset moves the joint's whole travel inside the 0..4095
frame. We move each joint's swept middle to read 2048: centring is what makes a
travel that straddled 0/4095 describable at all (bring-up seed). Offsets are
modular, so an arithmetic result outside ±2047 is folded, never rejected (a
rejection once aborted a real calibration run).

What is refused, rather than turned into plausible-looking numbers:
travel beyond one revolution; a range too short for the margin at both ends;
and, under ``--skip-homing`` only, a sweep that wrapped or a band that
excludes the zero.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from lupin.bench.sweep import JointTrace
from lupin.config_models import JointConfig
from lupin.joints import COUNTS_PER_REV, RAD_PER_COUNT

CENTRE = 2048
OFFSET_LIMIT = 2047  # the register's sign-magnitude range


class CalibrationRefused(Exception):
    """A joint's sweep cannot be turned into a calibration; the message says why."""

    def __init__(self, joint: str, message: str) -> None:
        super().__init__(f"{joint}: {message}")
        self.joint = joint


def wrap(counts: int) -> int:
    """``counts`` modulo 4096, into -2048..2047."""
    return (counts + CENTRE) % COUNTS_PER_REV - CENTRE


def fold_offset(offset: int) -> int:
    """An offset into the register's ±2047: modulo 4096, never rejected.

    -2048 has no encoding, so it becomes -2047, one count away: the centre then
    reads 2047 instead of 2048 (0.0015 rad), and the zero records it.
    """
    folded = wrap(offset)
    return -OFFSET_LIMIT if folded == -CENTRE else folded


@dataclass(frozen=True)
class JointCalibration:
    """One joint's result: the offset to write and the zero/min/max in the new frame."""

    name: str
    id: int
    invert: bool
    old_offset: int
    new_offset: int
    old_zero: int  # counts, old frame
    zero: int  # counts, new frame
    min: int
    max: int
    measurement: dict[str, Any] = field(default_factory=dict)

    @property
    def delta(self) -> int:
        """How far the offset moves; every present reading moves by minus this (mod 4096)."""
        return wrap(self.new_offset - self.old_offset)

    @property
    def shift_rad(self) -> float:
        """What a pose angle gains so it still names the same physical position.

        A pose is radians about the zero; the old zero sits at ``old_zero - delta``
        in the new frame, so every pose moves by that distance from the new zero.
        """
        sign = -1 if self.invert else 1
        return sign * wrap(self.old_zero - self.delta - self.zero) * RAD_PER_COUNT

    @property
    def limits_rad(self) -> tuple[float, float]:
        sign = -1 if self.invert else 1
        a, b = (sign * (c - self.zero) * RAD_PER_COUNT for c in (self.min, self.max))
        return min(a, b), max(a, b)

    def to_new_frame(self, old_counts: int) -> int:
        return (old_counts - self.delta) % COUNTS_PER_REV


def pull_in(name: str, lo: float, hi: float, margin_rad: float) -> tuple[int, int]:
    """The soft-limit band: the stops ``lo..hi`` (counts) pulled in by the margin at both ends.

    A hard stop is where the operator stopped pushing, so a soft limit has to sit
    short of it (bring-up seed). Raises :class:`CalibrationRefused` when the range
    is too short to survive the margin at both ends.
    """
    margin = margin_rad / RAD_PER_COUNT
    lo_c, hi_c = math.ceil(lo + margin), math.floor(hi - margin)
    if hi_c - lo_c < 2:
        raise CalibrationRefused(
            name,
            f"swept only {(hi - lo) * RAD_PER_COUNT:.3f} rad, too short for the {margin_rad:g} "
            f"rad margin at both ends: sweep it from stop to stop (or leave it out with --joints)",
        )
    return max(lo_c, 0), min(hi_c, COUNTS_PER_REV - 1)


def plan_joint(
    joint: JointConfig,
    trace: JointTrace,
    old_offset: int,
    margin_rad: float,
    *,
    homing: bool,
) -> JointCalibration:
    """Turn one joint's sweep into its calibration, or raise :class:`CalibrationRefused`."""
    name = joint.name
    if trace.samples == 0:
        raise CalibrationRefused(name, "no position reading during the sweep: run lupin check")
    span_rad = trace.span * RAD_PER_COUNT
    if trace.span >= COUNTS_PER_REV:
        # No stops to calibrate against and no single-turn frame that fits (seed):
        # unlike a wrap there is no remedy, so it is its own case.
        raise CalibrationRefused(
            name,
            f"swept {span_rad:.2f} rad, more than one revolution: a continuously rotating "
            f"joint has no stops to calibrate; leave it out with --joints",
        )
    if homing:
        middle = round((trace.lo + trace.hi) / 2)
        new_offset = fold_offset(middle + old_offset - CENTRE)
        delta = wrap(new_offset - old_offset)
        # The unwrapped frame's values, moved into the new one: one shift for all of them.
        lift = (middle - delta) - (middle - delta) % COUNTS_PER_REV
        lo, hi = trace.lo - delta - lift, trace.hi - delta - lift
        zero = middle - delta - lift
    else:
        if trace.wrapped:
            raise CalibrationRefused(
                name,
                f"the sweep crossed the encoder's 0/4095 boundary ({trace.lo}..{trace.hi}); "
                f"without homing no zero/limit pair can describe it: run without --skip-homing",
            )
        new_offset, lo, hi, zero = old_offset, trace.lo, trace.hi, joint.zero
    lo_c, hi_c = pull_in(name, lo, hi, margin_rad)
    if not lo_c <= zero <= hi_c:
        # Reachable only under --skip-homing: a centred zero is the middle of its band.
        hint = "run without --skip-homing to centre it" if not homing else "sweep it again"
        raise CalibrationRefused(
            name,
            f"the zero ({zero} counts) is outside the swept band {lo_c}..{hi_c}: the joint "
            f"could never reach 0 rad; {hint}",
        )
    measurement: dict[str, Any] = {
        "swept_min": lo,
        "swept_max": hi,
        "swept_rad": round(span_rad, 4),
        "samples": trace.samples,
        "margin_rad": margin_rad,
        "homing_offset": new_offset,
        "previous_homing_offset": old_offset,
        "wrapped": trace.wrapped,
    }
    return JointCalibration(
        name=name,
        id=joint.id,
        invert=joint.invert,
        old_offset=old_offset,
        new_offset=new_offset,
        old_zero=joint.zero,
        zero=zero,
        min=lo_c,
        max=hi_c,
        measurement=measurement,
    )
