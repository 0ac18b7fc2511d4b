"""The arm commander's gates and the re-assert defences, with a fake clock."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from lupin.arm import ArmCommander, Refused, Torque
from lupin.config import load_profile
from lupin.joints import arm_geometry


@pytest.fixture()
def arm(tmp_path: Path) -> ArmCommander:
    profile = load_profile("so101", home=tmp_path)
    return ArmCommander(arm_geometry(profile.arm))


def all_joints(arm: ArmCommander, value: float = 0.0) -> dict[str, float]:
    return dict.fromkeys(arm.names, value)


def energise(arm: ArmCommander) -> None:
    for n in arm.names:
        arm.set_torque_state(n, Torque.ON)
    arm.gate_open = True


def test_nothing_commanded_until_every_joint_observed(arm: ArmCommander) -> None:
    energise(arm)
    partial = {n: 0.1 for n in arm.names[:-1]}
    arm.observe(partial, 0.0)
    assert not arm.seeded
    assert arm.goals(0.0) == {}
    with pytest.raises(Refused, match="not seeded") as info:
        arm.move({"elbow_flex": 0.2}, 1.0, 0.0)
    assert info.value.code == "not_seeded"
    arm.observe({arm.names[-1]: 0.1}, 0.01)
    assert arm.seeded
    # The startup pin: the first goals are the measured pose, not zero.
    assert arm.goals(0.02) == pytest.approx(all_joints(arm, 0.1))


def test_move_refused_with_torque_off_or_unknown(arm: ArmCommander) -> None:
    arm.observe(all_joints(arm), 0.0)
    with pytest.raises(Refused, match="torque is unknown") as info:
        arm.move({"elbow_flex": 0.2}, 1.0, 0.0)
    assert info.value.code == "torque_off"
    for n in arm.names:
        arm.set_torque_state(n, Torque.OFF)
    with pytest.raises(Refused, match="torque is off"):
        arm.move({"elbow_flex": 0.2}, 1.0, 0.0)


def test_estop_refuses_and_holds_measured(arm: ArmCommander) -> None:
    arm.observe(all_joints(arm), 0.0)
    energise(arm)
    arm.move({"elbow_flex": 1.0}, 2.0, 0.0)
    arm.observe({**all_joints(arm), "elbow_flex": 0.3}, 1.0)
    arm.estop = True
    arm.hold(1.0)
    with pytest.raises(Refused, match="E-stop"):
        arm.move({"elbow_flex": 0.2}, 1.0, 1.0)
    assert arm.goals(1.5)["elbow_flex"] == pytest.approx(0.3, abs=1e-6)


def test_goal_clamped_to_window(arm: ArmCommander) -> None:
    arm.observe(all_joints(arm), 0.0)
    energise(arm)
    result = arm.move({"shoulder_pan": 3.0}, 1.0, 0.0)
    assert result.targets["shoulder_pan"] == pytest.approx(math.radians(90))
    assert arm.goals(5.0)["shoulder_pan"] == pytest.approx(math.radians(90))


def test_resync_adopts_a_joint_moved_by_something_else(arm: ArmCommander) -> None:
    arm.observe(all_joints(arm), 0.0)
    energise(arm)
    # 0.05 rad off (droop, lag): kept.
    arm.observe({**all_joints(arm), "wrist_flex": 0.05}, 0.1)
    assert arm.goals(0.1)["wrist_flex"] == pytest.approx(0.0)
    # 0.2 rad off with no motion commanded on it: re-adopted, not yanked back.
    arm.observe({**all_joints(arm), "wrist_flex": 0.2}, 0.2)
    assert arm.goals(0.2)["wrist_flex"] == pytest.approx(0.2)


def test_no_resync_while_the_joint_is_moving(arm: ArmCommander) -> None:
    arm.observe(all_joints(arm), 0.0)
    energise(arm)
    arm.move({"elbow_flex": 1.0}, 2.0, 0.0)
    arm.observe(all_joints(arm), 1.0)  # lagging far behind mid-move
    assert arm.goals(2.0)["elbow_flex"] == pytest.approx(1.0)


def test_excluded_joint_gets_no_goal(arm: ArmCommander) -> None:
    arm.observe(all_joints(arm), 0.0)
    energise(arm)
    arm.excluded["gripper"] = "operating mode reads 1"
    assert "gripper" not in arm.goals(0.0)
    with pytest.raises(Refused, match="excluded"):
        arm.move({"gripper": 0.1}, 1.0, 0.0)
