"""Scoring one gain trial's step response, and reading a whole sweep as droop or saturation.

Pure: samples in, numbers out. The columns are the seed's (arm-gains sweep):

- error: how far from the goal the joint settles — the droop itself;
- Kp×error: constant across gains means proportional droop (the servo settles
  where Kp × error balances the holding torque, and Ki = 0 never integrates it
  away); not constant means something else;
- load: effort while holding, of 1000; near 1000 is torque saturation, not droop;
- settle: time to enter and stay in the band (2% of travel, at least 2 counts);
- ripple and reversals: peak-to-peak motion and direction changes while holding,
  the counter-check on raising gain, since a hunting servo buzzes rather than holds.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

from lupin.joints import RAD_PER_COUNT

SETTLE_FRACTION = 0.02
SETTLE_MIN_COUNTS = 2
TAIL_FRACTION = 0.25  # the final position is the mean of this last part of the trial
SATURATION_LOAD = 900  # of 1000: "pins near 1000"
DROOP_SPREAD = 1.5  # Kp×error within this factor across the sweep reads as proportional


@dataclass(frozen=True)
class Sample:
    t: float  # seconds since the step was commanded
    position: int  # counts
    load: int  # signed, of 1000
    temperature: int  # °C


@dataclass(frozen=True)
class TrialScore:
    kp: int
    ki: int
    kd: int
    start: float  # counts, resting before the step
    goal: int
    final: float
    error_rad: float
    reached: float  # 1 - error / |step|
    kp_error: float  # Kp × error (rad)
    load: float  # mean |load| while holding
    settle_s: float | None  # None: never stayed inside the band
    ripple_rad: float
    reversals: int


def score_trial(
    samples: Sequence[Sample],
    *,
    start: float,
    goal: int,
    step_counts: int,
    kp: int,
    ki: int,
    kd: int,
) -> TrialScore:
    """Score the samples taken from the step command on. ValueError if there are none."""
    if not samples:
        raise ValueError("a trial with no samples cannot be scored")
    tail = samples[-max(1, round(len(samples) * TAIL_FRACTION)) :]
    final = sum(s.position for s in tail) / len(tail)
    band = max(SETTLE_FRACTION * abs(final - start), SETTLE_MIN_COUNTS)
    outside = [i for i, s in enumerate(samples) if abs(s.position - final) > band]
    if not outside:
        settle_at: int | None = 0
    elif outside[-1] + 1 < len(samples):
        settle_at = outside[-1] + 1
    else:
        settle_at = None
    hold = list(samples[settle_at:]) if settle_at is not None else list(tail)
    positions = [s.position for s in hold]
    error = abs(goal - final) * RAD_PER_COUNT
    return TrialScore(
        kp=kp,
        ki=ki,
        kd=kd,
        start=start,
        goal=goal,
        final=final,
        error_rad=error,
        reached=1.0 - error / (abs(step_counts) * RAD_PER_COUNT) if step_counts else 0.0,
        kp_error=kp * error,
        load=sum(abs(s.load) for s in hold) / len(hold),
        settle_s=samples[settle_at].t if settle_at is not None else None,
        ripple_rad=(max(positions) - min(positions)) * RAD_PER_COUNT,
        reversals=_reversals(positions),
    )


def _reversals(positions: Sequence[int]) -> int:
    signs = [1 if b > a else -1 for a, b in itertools.pairwise(positions) if b != a]
    return sum(1 for a, b in itertools.pairwise(signs) if a != b)


def verdict(scores: Sequence[TrialScore]) -> str:
    """One line reading the sweep: droop, saturation, or neither."""
    if not scores:
        return "no trials completed: nothing to read"
    saturated = [s for s in scores if s.load >= SATURATION_LOAD]
    if saturated:
        gains = ", ".join(str(s.kp) for s in saturated)
        return (
            f"saturation: load pins near 1000 at Kp={gains}; the servo is out of torque, "
            f"and more gain will not close the error"
        )
    kps = sorted({s.kp for s in scores})
    if len(kps) < 2:
        return _ki_verdict(scores)
    ordered = sorted(scores, key=lambda s: (s.kp, s.ki))
    lo, hi = ordered[0], ordered[-1]
    low, high = min(s.load for s in scores), max(s.load for s in scores)
    loads = f"{low:.0f}" if round(low) == round(high) else f"{low:.0f}-{high:.0f}"
    measurable = [s for s in ordered if s.error_rad >= RAD_PER_COUNT]
    if len(measurable) < 2:
        return f"error under one count at every gain (load {loads} of 1000): nothing to tune"
    products = [s.kp_error for s in measurable]
    spread = max(products) / min(products)
    fall = lo.error_rad / hi.error_rad if hi.error_rad else float("inf")
    rise = hi.kp / lo.kp if lo.kp else float("inf")
    if spread <= DROOP_SPREAD and fall > 1:
        return (
            f"droop: error fell {fall:.1f}x as Kp rose {rise:.0f}x, Kp×error held within "
            f"{spread:.2f}x, and load stayed at {loads} of 1000, far from saturation"
        )
    return (
        f"not proportional droop: Kp×error varies {spread:.1f}x across the sweep; error "
        f"fell {fall:.1f}x as Kp rose {rise:.0f}x (load {loads} of 1000)"
    )


def _ki_verdict(scores: Sequence[TrialScore]) -> str:
    ordered = sorted(scores, key=lambda s: s.ki)
    if len(ordered) < 2:
        return "one trial: no law to read; sweep at least two gains"
    base = ordered[0]
    best = min(ordered, key=lambda s: s.error_rad)

    def settle(s: TrialScore) -> str:
        return f"{s.settle_s:.2f} s" if s.settle_s is not None else "never"

    if best is base or best.error_rad >= base.error_rad - RAD_PER_COUNT:
        return (
            f"Ki sweep at Kp={base.kp}: no Ki improved on ki={base.ki} "
            f"(error {base.error_rad:.3f} rad, settling {settle(base)})"
        )
    return (
        f"Ki sweep at Kp={base.kp}: ki={best.ki} reached {best.reached:.1%} "
        f"(error {best.error_rad:.3f} rad); settling went {settle(base)} -> {settle(best)} "
        f"against ki={base.ki}"
    )
