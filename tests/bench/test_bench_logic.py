"""The bench tools' pure parts: unwrapping, homing arithmetic, step scoring, LeRobot parsing."""

from __future__ import annotations

import io
import os
import re
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from lupin.bench.homing import CalibrationRefused, fold_offset, plan_joint
from lupin.bench.lerobot import export_calibration, parse_calibration, recorded_sweeps
from lupin.bench.offsets import read_backup, write_backup
from lupin.bench.step_response import Sample, score_trial, verdict
from lupin.bench.sweep import JointTrace, SweepRecorder
from lupin.cli.bench_io import Terminal
from lupin.config import ConfigError, load_profile
from lupin.config_models import JointConfig
from lupin.joints import RAD_PER_COUNT


@pytest.mark.parametrize(
    ("raw", "folded"),
    [(3056, -1040), (-1040, -1040), (2152, -1944), (2047, 2047), (-2047, -2047),
     (2048, -2047), (-2048, -2047), (4096 + 5, 5), (0, 0)],
)  # fmt: skip
def test_offsets_fold_modulo_4096_never_reject(raw: int, folded: int) -> None:
    assert fold_offset(raw) == folded
    assert abs(fold_offset(raw)) <= 2047


def trace(*raw: int) -> JointTrace:
    t = JointTrace("j", 1)
    for r in raw:
        t.add(r)
    return t


def test_unwrap_across_4095_to_0_both_ways() -> None:
    up = trace(4000, 4090, 10, 100)
    assert (up.lo, up.hi, up.crossings, up.wrapped) == (4000, 4196, 1, True)
    down = trace(100, 10, 4090, 4000, 4090, 50)
    assert (down.lo, down.hi, down.crossings, down.wrapped) == (-96, 100, 2, True)
    plain = trace(2048, 1000, 3000)
    assert (plain.lo, plain.hi, plain.span, plain.wrapped) == (1000, 3000, 2000, False)


def test_recorder_counts_missed_readings() -> None:
    rec = SweepRecorder.for_joints({"a": 1, "b": 2})
    rec.add({"a": 10, "b": None})
    rec.add({"a": 20})
    assert rec.traces["a"].samples == 2 and rec.missed == {"b": 2}


def joint(zero: int = 2048, invert: bool = False) -> JointConfig:
    return JointConfig(name="j", id=1, zero=zero, min=0, max=4095, invert=invert)


@given(
    old_offset=st.integers(-2047, 2047),
    lo=st.integers(-1500, 4000),
    span=st.integers(300, 4000),
    old_zero=st.integers(0, 4095),
    invert=st.booleans(),
    pose=st.floats(-3.0, 3.0),
)
def test_centring_keeps_every_pose_on_the_same_physical_position(
    old_offset: int, lo: int, span: int, old_zero: int, invert: bool, pose: float
) -> None:
    t = trace(lo % 4096)
    t.lo, t.hi = lo, lo + span
    cal = plan_joint(joint(old_zero, invert), t, old_offset, 0.05, homing=True)
    assert -2047 <= cal.new_offset <= 2047
    assert cal.zero in (2047, 2048)
    assert 0 <= cal.min < cal.zero < cal.max <= 4095
    # The physical middle of the sweep reads the zero.
    middle_actual = round((t.lo + t.hi) / 2) + old_offset
    assert (middle_actual - cal.new_offset) % 4096 == cal.zero
    # A pose migrated by the shift names the same physical position.
    sign = -1 if invert else 1
    before = old_zero + sign * pose / RAD_PER_COUNT + old_offset
    after = cal.zero + sign * (pose + cal.shift_rad) / RAD_PER_COUNT + cal.new_offset
    assert abs((after - before + 2048) % 4096 - 2048) < 1e-6


def test_skip_homing_keeps_the_zero_and_offset() -> None:
    cal = plan_joint(joint(2000), trace(2000, 1000, 3000), 7, 0.05, homing=False)
    assert (cal.new_offset, cal.zero, cal.shift_rad) == (7, 2000, 0.0)
    assert (cal.min, cal.max) == (1033, 2967)


@pytest.mark.parametrize(
    ("raw", "homing", "needle"),
    [
        ((0, 2000, 4000, 1904, 3904), True, "more than one revolution"),
        ((2048, 2070), True, "too short for the 0.05 rad margin"),
        ((4000, 4090, 10, 300), False, "crossed the encoder's 0/4095 boundary"),
        ((2100, 3000), False, "zero (2048 counts) is outside the swept band"),
    ],
)
def test_refusals(raw: tuple[int, ...], homing: bool, needle: str) -> None:
    with pytest.raises(CalibrationRefused, match=re.escape(needle)):
        plan_joint(joint(), trace(*raw), 0, 0.05, homing=homing)


def samples(positions: list[int], load: int = 100, dt: float = 0.02) -> list[Sample]:
    return [Sample(i * dt, p, load, 30) for i, p in enumerate(positions)]


def test_score_a_clean_step_with_droop() -> None:
    # 2048 -> goal 1918, settling 20 counts short (droop toward the goal's far side).
    path = [2048, 2000, 1960, 1945, 1938, *[1938] * 45]
    s = score_trial(samples(path), start=2048, goal=1918, step_counts=-130, kp=16, ki=0, kd=32)
    assert s.final == 1938 and s.error_rad == pytest.approx(20 * RAD_PER_COUNT)
    assert s.reached == pytest.approx(1 - 20 / 130)
    assert s.kp_error == pytest.approx(16 * 20 * RAD_PER_COUNT)
    assert s.settle_s == pytest.approx(0.08)  # inside 2.2 counts (2% of 110) from sample 4
    assert (s.ripple_rad, s.reversals, s.load) == (0.0, 0, 100)


def test_score_counts_ripple_and_reversals_while_holding() -> None:
    path = [2048, 1990, 1940, *[1920, 1921] * 20]
    s = score_trial(samples(path), start=2048, goal=1918, step_counts=-130, kp=64, ki=0, kd=32)
    assert s.ripple_rad == pytest.approx(RAD_PER_COUNT)
    assert s.reversals >= 30


def make(kp: int, error_counts: float, load: int = 150):  # type: ignore[no-untyped-def]
    final = 1918 + round(error_counts)
    return score_trial(
        samples([2048, *[final] * 20], load=load),
        start=2048, goal=1918, step_counts=-130, kp=kp, ki=0, kd=32,
    )  # fmt: skip


def test_verdict_reads_droop_saturation_and_neither() -> None:
    droop = [make(16, 44), make(32, 22), make(64, 11), make(128, 6)]
    assert verdict(droop).startswith("droop: error fell 7.3x as Kp rose 8x")
    assert verdict([make(16, 44), make(32, 40, load=990)]).startswith("saturation")
    assert verdict([make(16, 44), make(32, 44)]).startswith("not proportional droop")
    assert verdict([make(16, 44)]).startswith("one trial")


def test_lerobot_export_and_strict_parse() -> None:
    profile = load_profile("so101")
    offsets = {j.name: 10 * j.id for j in profile.arm.joints}
    data = export_calibration(profile, offsets, {"gripper": (1850, 3010)})
    assert (data["gripper"]["range_min"], data["gripper"]["range_max"]) == (1850, 3010)
    assert data["elbow_flex"]["range_min"] == profile.joint("elbow_flex").min  # no sweep
    parsed = parse_calibration(data, profile, "f.json")
    assert parsed["gripper"].homing_offset == 60 and parsed["gripper"].range_min == 1850
    bad = {"elbow_flex": {**data["elbow_flex"], "drive_mode": 1}}
    with pytest.raises(ConfigError, match=r"elbow_flex.drive_mode: 1, but the profile has invert"):
        parse_calibration(bad, profile, "f.json")
    extra = {"elbow_flex": {**data["elbow_flex"], "calib_mode": "x"}}
    with pytest.raises(ConfigError, match="unknown fields"):
        parse_calibration(extra, profile, "f.json")
    with pytest.raises(ConfigError, match="not an arm joint"):
        parse_calibration({"left": data["elbow_flex"]}, profile, "f.json")


def test_only_a_sweep_about_the_offset_the_servo_holds_is_exported() -> None:
    measured = {"swept_min": 900, "swept_max": 3100, "homing_offset": 12}
    joints = {
        "elbow_flex": {"zero": 2000, "measurement": measured},
        "wrist_flex": {"zero": 2000, "measurement": {**measured, "homing_offset": 40}},
        "gripper": {"zero": 2000},
    }
    offsets = {"elbow_flex": 12, "wrist_flex": 41, "gripper": 0}
    assert recorded_sweeps(joints, offsets) == {"elbow_flex": (900, 3100)}


def test_backups_taken_within_one_second_never_overwrite_each_other(tmp_path: Path) -> None:
    joints = load_profile("so101").arm.joints
    path = tmp_path / "arm_offsets_backup.yaml"
    kept = []
    for value in (1, 2, 3):
        kept.append(write_backup(path, {"elbow_flex": value}, joints, profile="so101", port="p"))
    assert kept[0] is None and kept[1] is not None and kept[2] is not None
    assert kept[1] != kept[2]
    values = [read_backup(p, joints)["elbow_flex"] for p in (kept[1], kept[2], path)]
    assert values == [1, 2, 3]


async def test_terminal_yes_end_of_input_and_answers() -> None:
    r, w = os.pipe()
    os.write(w, b"y\nnope\n")
    os.close(w)
    out = io.StringIO()
    with os.fdopen(r) as stdin:
        term = Terminal(False, stdin=stdin, out=out)
        assert await term.confirm("one?") is True
        assert await term.confirm("two?") is False
        assert await term.confirm("three?") is False  # end of input is no
        assert await Terminal(True, stdin=stdin, out=out).confirm("four?") is True
