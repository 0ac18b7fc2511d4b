"""The arm service layer against the simulated bus: sliders, torque gates, presets,
poses, closed-loop status, heal and auto-home — judged by the packets the servos
received and the state the service layer reports."""

from __future__ import annotations

import asyncio
import math
import time
from pathlib import Path

import pytest

from lupin import api_models as m
from lupin import control_table as ct
from lupin.daemon import Daemon, DaemonOptions
from lupin.protocol import ServoError
from lupin.services import ServiceError
from lupintest.harness import Sim, wait_for

GOAL_POS = ct.REGISTERS["goal_position"].address
TORQUE = ct.REGISTERS["torque_enable"].address
ARM_IDS = [1, 2, 3, 4, 5, 6]
TOL_DEG = 3.5  # droop at the sim's default gain is ~2 deg on the shoulder


def joint_deg(d: Daemon, name: str) -> float:
    for j in d.services.state().joints:
        if j.name == name:
            assert j.position_deg is not None
            return j.position_deg
    raise KeyError(name)


def status(d: Daemon, name: str) -> str:
    return next(j.status for j in d.services.state().joints if j.name == name)


async def torque_on(d: Daemon) -> None:
    reply = await d.services.set_torque(m.TorqueRequest(enabled=True))
    assert reply.torque == "on"


async def test_slider_refused_while_limp_then_moves_and_settles(sim: Sim, daemon: Daemon) -> None:
    svc = daemon.services
    with pytest.raises(ServiceError) as info:
        await svc.set_joint("elbow_flex", m.JointRequest(angle_deg=20))
    assert (info.value.code, info.value.status) == ("torque_off", 409)
    assert sim.all_writes() == []
    await torque_on(daemon)
    t0 = time.monotonic()
    reply = await svc.set_joint("elbow_flex", m.JointRequest(angle_deg=20, speed_deg_s=40))
    assert reply.targets_deg == {"elbow_flex": pytest.approx(20)}
    assert reply.travel_s == pytest.approx(0.5, abs=0.02)  # |20 - ~0| / 40
    await wait_for(lambda: status(daemon, "elbow_flex") == "moving", timeout=0.5)
    await wait_for(lambda: status(daemon, "elbow_flex") == "settled", timeout=3.0)
    assert abs(joint_deg(daemon, "elbow_flex") - 20) < TOL_DEG
    assert time.monotonic() - t0 >= 0.45  # settled from measurement, not from the ack


async def test_slider_refusals_change_nothing(sim: Sim, daemon: Daemon) -> None:
    svc = daemon.services
    await torque_on(daemon)
    t0 = time.monotonic()
    cases = [
        ("elbow_flex", 95.0, "out_of_window", 400),
        ("elbow", 10.0, "unknown_joint", 404),
        ("gripper", 10.0, "use_gripper", 400),
    ]
    for joint, angle, code, st in cases:
        with pytest.raises(ServiceError) as info:
            await svc.set_joint(joint, m.JointRequest(angle_deg=angle))
        assert (info.value.code, info.value.status) == (code, st)
    await svc.set_estop(m.EstopRequest(engaged=True))
    with pytest.raises(ServiceError) as info:
        await svc.set_joint("elbow_flex", m.JointRequest(angle_deg=10))
    assert info.value.code == "estop"
    await asyncio.sleep(0.2)
    moved = [w for w in sim.bus.writes_to(GOAL_POS, since=t0) if w.id == 3]
    # Only the E-stop's hold at the measured (drooped) pose; never toward 10 or 95 deg.
    assert all(abs(w.value("goal_position") - 2048) < 30 for w in moved)  # type: ignore[operator]


async def test_slider_refused_until_seeded(sim: Sim) -> None:
    sim.bus.kill(3)
    d = Daemon(sim.profile, DaemonOptions(bus_port=sim.path, auto_home=False))
    await d.start()
    try:
        await asyncio.sleep(0.3)
        assert not d.arm.seeded
        with pytest.raises(ServiceError) as info:
            await d.services.set_torque(m.TorqueRequest(enabled=True))
        assert info.value.code == "not_seeded"
        assert sim.all_writes() == []
        sim.bus.revive(3)
        await wait_for(lambda: d.arm.seeded)
    finally:
        await d.stop()


async def test_gripper_maps_hmi_degrees_with_profile_sense(sim: Sim, daemon: Daemon) -> None:
    await torque_on(daemon)
    grip = sim.profile.arm.gripper
    assert grip is not None
    reply = await daemon.services.set_gripper(m.JointRequest(angle_deg=-30, speed_deg_s=60))
    assert reply.targets_deg == {"gripper": -30}
    # HMI -30 is OPEN on this jaw: the joint goes to open_rad.
    await wait_for(lambda: status(daemon, "gripper") == "settled", timeout=4.0)
    assert joint_deg(daemon, "gripper") == pytest.approx(math.degrees(grip.open_rad), abs=TOL_DEG)
    with pytest.raises(ServiceError):
        await daemon.services.set_gripper(m.JointRequest(angle_deg=31))


async def test_preset_then_slider_on_another_joint_does_not_yank_it_back(
    sim: Sim, daemon: Daemon
) -> None:
    svc = daemon.services
    await torque_on(daemon)
    reply = await svc.go_preset("pick")
    assert reply.travel_s == 3.0
    assert "gripper" not in reply.targets_deg  # presets never move the gripper
    await asyncio.sleep(3.4)
    pick = sim.profile.presets["pick"]
    for name, rad in pick.items():
        assert joint_deg(daemon, name) == pytest.approx(math.degrees(rad), abs=TOL_DEG)
    await svc.set_joint("wrist_roll", m.JointRequest(angle_deg=30, speed_deg_s=90))
    await asyncio.sleep(0.8)
    for name, rad in pick.items():
        assert joint_deg(daemon, name) == pytest.approx(math.degrees(rad), abs=TOL_DEG)
    assert joint_deg(daemon, "wrist_roll") == pytest.approx(30, abs=TOL_DEG)


async def test_joint_moved_by_something_else_is_adopted_not_yanked(
    sim: Sim, daemon: Daemon
) -> None:
    await torque_on(daemon)
    # The elbow trips and is pushed 0.46 rad away while unloaded: something other
    # than the daemon moved it, so the commanded pose adopts the measurement.
    sim.bus.servo(3).unload(ServoError.OVERLOAD)
    sim.bus.servo(3).move_by_hand(2048 + 300)
    await wait_for(lambda: daemon.arm.resyncs >= 1, timeout=1.0)
    elbow = next(j for j in daemon.services.state().joints if j.name == "elbow_flex")
    assert elbow.commanded_deg == pytest.approx(elbow.position_deg, abs=1.0)
    # A slider on another joint, then heal re-energising the elbow: it stays put.
    await daemon.services.set_joint("wrist_flex", m.JointRequest(angle_deg=-20))
    assert (await daemon.services.heal()).result == "healed"
    await asyncio.sleep(1.0)
    assert sim.bus.servo(3).torque
    assert abs(sim.bus.servo(3).present_position - 2348) < 25


async def test_init_drives_to_zero(sim: Sim, daemon: Daemon) -> None:
    for sid in (2, 3):
        sim.bus.servo(sid).move_by_hand(2048 + 200)
    await asyncio.sleep(0.1)
    await torque_on(daemon)
    reply = await daemon.services.init_arm()
    assert reply.travel_s == 3.0 and set(reply.targets_deg) == {
        "shoulder_pan",
        "shoulder_lift",
        "elbow_flex",
        "wrist_flex",
        "wrist_roll",
    }
    await asyncio.sleep(3.4)
    assert joint_deg(daemon, "shoulder_lift") == pytest.approx(0, abs=TOL_DEG)
    assert joint_deg(daemon, "elbow_flex") == pytest.approx(0, abs=TOL_DEG)


async def test_disable_closes_gate_then_cuts_torque(sim: Sim, daemon: Daemon) -> None:
    await torque_on(daemon)
    await daemon.services.set_joint("elbow_flex", m.JointRequest(angle_deg=30, speed_deg_s=20))
    await asyncio.sleep(0.3)
    t0 = time.monotonic()
    reply = await daemon.services.set_torque(m.TorqueRequest(enabled=False))
    assert reply.torque == "off"
    assert all(not sim.bus.servo(i).torque for i in ARM_IDS)
    await asyncio.sleep(0.3)
    # No goal went out after torque was cut: the gate closed first.
    cut = min(w.t for w in sim.bus.writes_to(TORQUE, since=t0))
    assert [w for w in sim.bus.writes_to(GOAL_POS, since=cut) if w.id in ARM_IDS] == []
    with pytest.raises(ServiceError) as info:
        await daemon.services.set_joint("elbow_flex", m.JointRequest(angle_deg=10))
    assert info.value.code == "torque_off"


async def test_tripped_servo_is_reported_stalled_with_diagnosis(sim: Sim, daemon: Daemon) -> None:
    await torque_on(daemon)
    await daemon.services.set_joint("shoulder_lift", m.JointRequest(angle_deg=40, speed_deg_s=20))
    await asyncio.sleep(0.4)
    sim.bus.servo(2).unload(ServoError.OVERLOAD)  # the runbook's cooking shoulder
    await wait_for(lambda: status(daemon, "shoulder_lift") == "stalled", timeout=4.0)
    events = daemon.services.state().events
    assert events and events[-1].joint == "shoulder_lift"
    assert "likely a servo trip" in events[-1].diagnosis
    assert "overload" in events[-1].diagnosis
    assert events[-1].error_deg > 8


async def test_heal_unknown_when_bus_unplugged_and_attempts_nothing(
    sim: Sim, daemon: Daemon
) -> None:
    for sid in sim.bus.ids:
        sim.bus.kill(sid)
    t0 = time.monotonic()
    reply = await daemon.services.heal()
    assert reply.result == "unknown"
    assert sim.all_writes(since=t0) == []


async def test_heal_reenables_an_unloaded_servo_without_a_jump(sim: Sim, daemon: Daemon) -> None:
    await torque_on(daemon)
    sim.bus.servo(2).unload(ServoError.OVERLOAD)
    sim.bus.servo(2).move_by_hand(2048 - 120)  # it sagged while unloaded
    await asyncio.sleep(0.2)
    reply = await daemon.services.heal()
    assert reply.result == "healed"
    assert any("shoulder_lift" in d and "re-enabled" in d for d in reply.details)
    assert sim.bus.servo(2).torque
    await asyncio.sleep(0.3)
    assert abs(sim.bus.servo(2).present_position - (2048 - 120)) < 30  # held, not yanked
    assert (await daemon.services.heal()).result == "healthy"


async def test_heal_failed_names_a_missing_servo(sim: Sim, daemon: Daemon) -> None:
    sim.bus.kill(5)
    reply = await daemon.services.heal()
    assert reply.result == "failed"
    assert any("wrist_roll (id 5) does not answer" in d for d in reply.details)


async def test_auto_home_parks_at_home(sim: Sim, lupin_home: Path) -> None:
    d = Daemon(sim.profile, DaemonOptions(bus_port=sim.path, auto_home=True))
    await d.start()
    try:
        await wait_for(lambda: d.auto_home_state == "done", timeout=8.0)
        await asyncio.sleep(3.3)
        for name, rad in sim.profile.presets["home"].items():
            assert joint_deg(d, name) == pytest.approx(math.degrees(rad), abs=TOL_DEG)
    finally:
        await d.stop()


async def test_taught_poses_save_list_go_delete(sim: Sim, daemon: Daemon, lupin_home: Path) -> None:
    svc = daemon.services
    sim.bus.servo(3).move_by_hand(2048 + 100)
    await asyncio.sleep(0.1)
    t0 = time.monotonic()
    saved = await svc.save_pose("reach", m.PoseSaveRequest())
    assert saved.joints_rad["elbow_flex"] == pytest.approx(100 * 2 * math.pi / 4096, abs=0.002)
    assert "gripper" not in saved.joints_rad
    assert sim.all_writes(since=t0) == []  # capture is read-only
    assert (lupin_home / "poses.yaml").exists()
    await torque_on(daemon)
    far = {"elbow_flex": 1.0, "shoulder_lift": 0.0}
    await svc.save_pose("far", m.PoseSaveRequest(joints_rad=far))
    assert (lupin_home / "poses.yaml.bak").exists()
    listed = {p.name: p for p in svc.list_poses().poses}
    assert set(listed) == {"reach", "far"} and listed["reach"].distance_rad is not None
    with pytest.raises(ServiceError) as info:
        await svc.go_pose("far", m.PoseGoRequest())
    assert info.value.code == "too_far"
    await svc.set_joint("elbow_flex", m.JointRequest(angle_deg=0, speed_deg_s=60))
    await asyncio.sleep(0.6)
    reply = await svc.go_pose("reach", m.PoseGoRequest(speed_rad_s=0.5))
    assert reply.largest_travel_rad <= 0.35
    assert reply.travel_s == pytest.approx(reply.largest_travel_rad / 0.5, abs=0.06)
    await asyncio.sleep(reply.travel_s + 0.6)
    assert abs(sim.bus.servo(3).present_position - 2148) < 25
    svc.delete_pose("far")
    assert [p.name for p in svc.list_poses().poses] == ["reach"]
    with pytest.raises(ServiceError):
        svc.delete_pose("far")


async def test_pose_go_stops_on_sustained_lag(sim: Sim, daemon: Daemon) -> None:
    await torque_on(daemon)
    await daemon.services.save_pose("up", m.PoseSaveRequest(joints_rad={"shoulder_lift": 0.3}))
    sim.bus.latch(2)  # ignores every write: the joint never follows
    await daemon.services.go_pose("up", m.PoseGoRequest(speed_rad_s=0.2))
    await wait_for(lambda: status(daemon, "shoulder_lift") == "stalled", timeout=4.0)
    # Stopped where it is: the command is re-pinned to the measured pose.
    assert daemon.arm.commanded is not None
    assert abs(daemon.arm.commanded["shoulder_lift"] - daemon.arm.measured["shoulder_lift"]) < 0.02
