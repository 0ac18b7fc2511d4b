"""Joint windows and count/radian conversion."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from lupin.config_models import JointConfig
from lupin.joints import RAD_PER_COUNT, geometry, joint_window_deg


def joint(**kw: object) -> JointConfig:
    return JointConfig.model_validate({"name": "j", "id": 1, **kw})


def test_window_is_envelope_when_servo_reaches_past_it() -> None:
    # Servo limit ±135°: the ±90° envelope wins (deliberate under-travel).
    assert joint_window_deg(joint(zero=2048, min=512, max=3584), 90) == (-90, 90)


def test_window_tightens_to_asymmetric_servo_limit_rounded_inward() -> None:
    # min: (1100-2048) counts = -83.32°, max: (3000-2048) = 83.67° -> (-83, 83).
    assert joint_window_deg(joint(zero=2048, min=1100, max=3000), 90) == (-83, 83)


def test_window_rounds_inward_on_both_sides() -> None:
    # -30.05° rounds to -30 (not -31); 44.91° rounds to 44 (not 45).
    lo = 2048 - round(30.05 / 360 * 4096)
    hi = 2048 + round(44.91 / 360 * 4096)
    w = joint_window_deg(joint(zero=2048, min=lo, max=hi), 90)
    assert w == (-30, 44)


def test_inverted_joint_swaps_sides() -> None:
    assert joint_window_deg(joint(zero=2048, min=1100, max=2900, invert=True), 90) == (-74, 83)


def test_per_joint_envelope_overrides_arm_default() -> None:
    assert joint_window_deg(joint(envelope_deg=45), 90) == (-45, 45)


def test_exact_90_is_not_lost_to_float_noise() -> None:
    assert joint_window_deg(joint(zero=2048, min=1024, max=3072), 90) == (-90, 90)


def test_rad_to_counts_clamps_to_servo_limits() -> None:
    g = geometry(joint(zero=2048, min=1024, max=3072), 90)
    assert g.rad_to_counts(0.0) == 2048
    assert g.rad_to_counts(10.0) == 3072
    assert g.rad_to_counts(-10.0) == 1024
    assert g.clamp_rad(3.0) == math.radians(90)


@given(st.integers(min_value=1024, max_value=3072), st.booleans())
def test_counts_round_trip(counts: int, invert: bool) -> None:
    g = geometry(joint(zero=2048, min=1024, max=3072, invert=invert), 90)
    rad = g.counts_to_rad(counts)
    assert g.rad_to_counts(rad) == counts
    assert abs(rad) <= 1024 * RAD_PER_COUNT + 1e-12
