"""The arm teleop integrator (runbook's arm_teleop), with a fake clock."""

from __future__ import annotations

import logging
import math
from pathlib import Path

import pytest

from lupin.arm import ArmCommander, Torque
from lupin.config import load_profile
from lupin.config_models import RobotProfile
from lupin.joints import arm_geometry
from lupin.pad import PadFrame
from lupin.pad_mapping import PadMapping, load_mapping
from lupin.teleop import ArmTeleop, resolve_roles, trigger_pull

STEP = 0.15
HALF_PI = math.radians(90)


@pytest.fixture()
def so101(tmp_path: Path) -> RobotProfile:
    return load_profile("so101", home=tmp_path)


def teleop_for(profile: RobotProfile, layout: str = "xbox-bluetooth") -> ArmTeleop:
    geo = arm_geometry(profile.arm)
    return ArmTeleop(
        load_mapping(layout),
        list(geo),
        {n: g.window_rad for n, g in geo.items()},
        gripper=profile.arm.gripper,
    )


def bt_frame(
    *,
    buttons: tuple[int, ...] = (),
    dpad_x: float = 0.0,
    dpad_y: float = 0.0,
    rt: float = 1.0,
    lt: float = 1.0,
) -> PadFrame:
    """Bluetooth layout: D-pad axes 6/7 (up/left read +1), RT/LT axes 4/5 rest +1."""
    axes = (0.0, 0.0, 0.0, 0.0, rt, lt, dpad_x, dpad_y)
    return PadFrame(0.0, axes, tuple(1 if i in buttons else 0 for i in range(15)))


B, X, Y, A, LB, MENU, VIEW = 1, 3, 4, 0, 6, 11, 10


def rest(names: list[str], value: float = 0.0) -> dict[str, float]:
    return dict.fromkeys(names, value)


def test_roles_map_onto_both_profiles(so101: RobotProfile, tmp_path: Path) -> None:
    assert resolve_roles([j.name for j in so101.arm.joints]) == {
        "shoulder_pan": "shoulder_pan",
        "shoulder_lift": "shoulder_lift",
        "elbow": "elbow_flex",
        "wrist": "wrist_flex",
        "wrist_roll": "wrist_roll",
    }
    mecanum = load_profile("mecanum", home=tmp_path)
    roles = resolve_roles([j.name for j in mecanum.arm.joints])
    assert roles["elbow"] == "elbow" and roles["wrist"] == "wrist"
    assert "wrist_roll" not in roles  # no such joint: the control is simply inert


def test_held_button_steps_0_15_per_tick(so101: RobotProfile) -> None:
    t = teleop_for(so101)
    measured = rest([*t.arm_joints, "gripper"], 0.1)
    t.on_frame(bt_frame(buttons=(B,)))
    assert t.step(measured, 0.0) == {"shoulder_pan": pytest.approx(0.25)}
    assert t.step(measured, 0.1) == {"shoulder_pan": pytest.approx(0.40)}
    t.on_frame(bt_frame(buttons=(X,)))  # the minus button
    assert t.step(measured, 0.2) == {"shoulder_pan": pytest.approx(0.25)}
    assert t.duration == pytest.approx(0.1)  # 10 Hz


def test_clamped_to_the_joint_window(so101: RobotProfile) -> None:
    t = teleop_for(so101)
    measured = rest([*t.arm_joints, "gripper"], HALF_PI - 0.2)
    t.on_frame(bt_frame(buttons=(Y,)))
    out = [t.step(measured, i / 10)["shoulder_lift"] for i in range(4)]
    assert out == pytest.approx([HALF_PI - 0.05, HALF_PI, HALF_PI, HALF_PI])


def test_seed_gate_nothing_until_every_arm_joint_observed(so101: RobotProfile) -> None:
    t = teleop_for(so101)
    t.on_frame(bt_frame(buttons=(B,), dpad_y=1.0))
    partial = rest(t.arm_joints[:-1])
    assert t.step(partial, 0.0) == {}
    full = rest(t.arm_joints)
    assert set(t.step(full, 0.1)) == {"shoulder_pan", "elbow_flex"}


def test_reseed_from_measured_on_the_idle_to_active_edge(so101: RobotProfile) -> None:
    t = teleop_for(so101)
    measured = rest(t.arm_joints)
    t.on_frame(bt_frame(buttons=(B,)))
    t.step(measured, 0.0)
    # Held: open loop, the integrator does not re-read a lagging measurement.
    assert t.step({**measured, "shoulder_pan": 0.05}, 0.1) == {"shoulder_pan": pytest.approx(0.3)}
    t.on_frame(bt_frame())
    assert t.step(measured, 0.2) == {}
    # Gravity sagged the joint to 0.5 meanwhile: the next tap starts from there.
    t.on_frame(bt_frame(buttons=(B,)))
    out = t.step({**measured, "shoulder_pan": 0.5}, 0.3)
    assert out == {"shoulder_pan": pytest.approx(0.65)}


def test_shoulder_silenced_while_lb_held_but_dpad_live(so101: RobotProfile) -> None:
    t = teleop_for(so101)
    measured = rest(t.arm_joints)
    t.on_frame(bt_frame(buttons=(LB, B, Y), dpad_y=1.0))
    assert t.step(measured, 0.0) == {"elbow_flex": pytest.approx(STEP)}
    t.on_frame(bt_frame(buttons=(B,)))  # LB released: the shoulder is live again
    assert t.step(measured, 0.1) == {"shoulder_pan": pytest.approx(STEP)}


def test_a_shoulder_tap_under_lb_is_not_replayed_after_release(so101: RobotProfile) -> None:
    t = teleop_for(so101)
    t.on_frame(bt_frame(buttons=(LB, B)))  # brushed B while driving
    t.on_frame(bt_frame())  # both released before the next tick
    assert t.step(rest(t.arm_joints), 0.0) == {}


def test_dpad_elbow_and_wrist_same_on_usb_and_bluetooth(so101: RobotProfile) -> None:
    results = []
    for layout, up, left in (("xbox-bluetooth", 1.0, 1.0), ("xbox-usb", -1.0, -1.0)):
        t = teleop_for(so101, layout)
        axes = [0.0] * 8
        axes[7], axes[6] = up, left
        t.on_frame(PadFrame(0.0, tuple(axes), (0,) * 15))
        results.append(t.step(rest(t.arm_joints), 0.0))
    assert (
        results[0]
        == results[1]
        == {
            "elbow_flex": pytest.approx(STEP),
            "wrist_flex": pytest.approx(STEP),
        }
    )


def test_wrist_roll_has_its_own_buttons(so101: RobotProfile, tmp_path: Path) -> None:
    t = teleop_for(so101)
    t.on_frame(bt_frame(buttons=(VIEW,)))
    assert t.step(rest(t.arm_joints), 0.0) == {"wrist_roll": pytest.approx(-STEP)}
    mecanum = teleop_for(load_profile("mecanum", home=tmp_path))
    mecanum.on_frame(bt_frame(buttons=(MENU,)))
    assert mecanum.step(rest([*mecanum.arm_joints, "gripper"]), 0.0) == {}


def test_a_tap_between_ticks_is_one_step(so101: RobotProfile) -> None:
    t = teleop_for(so101)
    t.on_frame(bt_frame(buttons=(A,)))
    t.on_frame(bt_frame())
    assert t.step(rest(t.arm_joints), 0.0) == {"shoulder_lift": pytest.approx(-STEP)}
    assert t.step(rest(t.arm_joints), 0.1) == {}


def test_vanished_pad_releases_every_control(so101: RobotProfile) -> None:
    t = teleop_for(so101)
    t.on_frame(bt_frame(buttons=(B,), dpad_x=1.0))
    t.step(rest(t.arm_joints), 0.0)
    t.on_frame(None)
    assert t.step(rest(t.arm_joints), 0.1) == {}
    assert not t.wants_tick


# -- the gripper on the triggers ---------------------------------------------------------


def test_trigger_pull_formula() -> None:
    assert trigger_pull(1.0, 1.0, -1.0) == 0.0
    assert trigger_pull(0.0, 1.0, -1.0) == 0.5
    assert trigger_pull(-1.0, 1.0, -1.0) == 1.0
    assert trigger_pull(-1.0, 0.0, 1.0) == 0.0  # clamped, never negative
    assert trigger_pull(1.2, -1.0, 1.0) == 1.0


def test_trigger_init_guard_ignores_the_bogus_zero(so101: RobotProfile) -> None:
    t = teleop_for(so101)
    measured = {**rest(t.arm_joints), "gripper": 0.0}
    # Before the first physical event some drivers report 0.0: with rest at +1 that
    # would read as a half pull and open the jaw by itself.
    t.on_frame(bt_frame(rt=0.0, lt=1.0))  # RT not yet moved, LT already reported rest
    assert t.step(measured, 0.0) == {}
    t.on_frame(bt_frame(rt=1.0, lt=1.0))  # the first real event: at rest
    assert t.step(measured, 0.1) == {}
    t.on_frame(bt_frame(rt=-1.0))  # RT fully pulled: open, toward open_rad = 1.2
    assert t.step(measured, 0.2) == {"gripper": pytest.approx(STEP)}
    t.on_frame(bt_frame(rt=0.0))  # now 0.0 is a genuine half pull
    assert t.step(measured, 0.3) == {"gripper": pytest.approx(STEP + STEP / 2)}


def test_gripper_held_until_observed(so101: RobotProfile) -> None:
    t = teleop_for(so101)
    t.on_frame(bt_frame(rt=-1.0, buttons=(B,)))
    assert t.step(rest(t.arm_joints), 0.0) == {"shoulder_pan": pytest.approx(STEP)}
    out = t.step({**rest(t.arm_joints), "gripper": 0.6}, 0.1)
    assert out["gripper"] == pytest.approx(0.75)


def test_gripper_close_and_clamp_to_open_closed(so101: RobotProfile) -> None:
    t = teleop_for(so101)
    t.on_frame(bt_frame(lt=-1.0))  # LT: close, toward closed_rad = 0.0
    measured = {**rest(t.arm_joints), "gripper": 0.2}
    assert [t.step(measured, i / 10)["gripper"] for i in range(3)] == pytest.approx(
        [0.05, 0.0, 0.0]
    )


def test_usb_triggers_ship_disabled(so101: RobotProfile) -> None:
    t = teleop_for(so101, "xbox-usb")
    axes = [0.0] * 8
    axes[5] = axes[2] = 1.0  # whatever the triggers read, the jaw must not creep
    t.on_frame(PadFrame(0.0, tuple(axes), (0,) * 11))
    assert t.step({**rest(t.arm_joints), "gripper": 0.5}, 0.0) == {}


def test_rest_near_zero_initialises_at_once(so101: RobotProfile) -> None:
    data = load_mapping("xbox-bluetooth").model_dump()
    data.update(gripper_open_rest=0.0, gripper_open_full=1.0)
    geo = arm_geometry(so101.arm)
    t = ArmTeleop(
        PadMapping.model_validate(data),
        list(geo),
        {n: g.window_rad for n, g in geo.items()},
        gripper=so101.arm.gripper,
    )
    t.on_frame(bt_frame(rt=0.5))
    assert t.step({**rest(t.arm_joints), "gripper": 0.0}, 0.0) == {"gripper": pytest.approx(0.075)}


# -- through the arm commander ---------------------------------------------------------------


def test_send_goes_through_the_commander_and_refusals_drop_the_step(
    so101: RobotProfile, caplog: pytest.LogCaptureFixture
) -> None:
    geo = arm_geometry(so101.arm)
    arm = ArmCommander(geo)
    arm.observe(dict.fromkeys(geo, 0.0), 0.0)
    t = teleop_for(so101)
    t.on_frame(bt_frame(buttons=(B,)))
    with caplog.at_level(logging.WARNING, logger="lupin.teleop"):
        for i in range(5):  # torque unknown: refused every tick, logged once
            assert t.send(arm, i / 10) is None
    assert t.refusals == 5
    assert len([r for r in caplog.records if "refused" in r.message]) == 1
    assert arm.commanded is not None and arm.commanded["shoulder_pan"] == 0.0
    for n in arm.names:
        arm.set_torque_state(n, Torque.ON)
    arm.gate_open = True
    arm.observe({"shoulder_pan": 0.02}, 0.6)
    result = t.send(arm, 0.6)
    # Re-seeded from measured after the dropped steps, not 5 steps ahead.
    assert result is not None
    assert result.targets == {"shoulder_pan": pytest.approx(0.17)}
    assert result.duration == pytest.approx(0.1)
