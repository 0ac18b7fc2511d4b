"""SimServo: the control table rules and the physics the seeds measured."""

from __future__ import annotations

import math
from typing import Any

import pytest

from lupin import control_table as ct
from lupin.protocol import ServoError
from lupin_adapters.sim.physics import DROOP_K, MAX_SPEED, SO101_SHOULDER_GRAVITY
from lupin_adapters.sim.servo import SimServo

REG = ct.REGISTERS
RAD_PER_COUNT = 2 * math.pi / 4096


def wr(servo: SimServo, name: str, value: int) -> None:
    """A client's WRITE of one register (goes through the servo's rules)."""
    reg = REG[name]
    servo.write(reg.address, ct.encode_value(reg, value))


def rd(servo: SimServo, name: str) -> int:
    """A client's READ of one register."""
    reg = REG[name]
    return ct.decode_value(reg, servo.read(reg.address, reg.size))


def holding(position: float = 2048, **kw: Any) -> SimServo:
    """A servo with torque on, holding where it is."""
    s = SimServo(1, position=position, **kw)
    wr(s, "torque_enable", 1)
    return s


def test_power_up_defaults() -> None:
    s = SimServo(3, position=1234)
    assert rd(s, "model") == 777 and rd(s, "firmware_major") == 3
    assert rd(s, "id") == 3
    assert (rd(s, "min_position_limit"), rd(s, "max_position_limit")) == (0, 4095)
    assert (rd(s, "p_coefficient"), rd(s, "d_coefficient"), rd(s, "i_coefficient")) == (32, 32, 0)
    assert rd(s, "torque_enable") == 0 and rd(s, "operating_mode") == 0
    assert rd(s, "present_voltage") == 51 and rd(s, "present_temperature") == 27
    assert rd(s, "lock") == 1  # EEPROM write-protected until a tool unlocks it
    assert rd(s, "present_position") == 1234 == rd(s, "goal_position")
    assert s.error == 0


def test_moves_to_goal_at_goal_speed() -> None:
    s = holding(1000)
    wr(s, "goal_speed", 500)
    wr(s, "goal_position", 2000)
    s.step(1.0)
    assert rd(s, "present_position") == pytest.approx(1500, abs=3)
    assert rd(s, "present_speed") == 500 and rd(s, "moving") == 1
    s.step(1.1)
    assert rd(s, "present_position") == 2000
    assert rd(s, "present_speed") == 0 and rd(s, "moving") == 0


def test_speed_zero_means_full_speed() -> None:
    s = holding(0)
    wr(s, "goal_position", 4000)
    s.step(0.5)
    assert rd(s, "present_position") == pytest.approx(MAX_SPEED * 0.5, abs=3)


def test_acceleration_ramps_up() -> None:
    s = holding(1000)
    wr(s, "acceleration", 10)  # 87 °/s² ≈ 990 counts/s²
    wr(s, "goal_position", 3000)
    s.step(0.5)
    a = 10 * 8.7 * 4096 / 360
    assert rd(s, "present_position") - 1000 == pytest.approx(0.5 * a * 0.25, rel=0.05)
    s.step(5)
    assert rd(s, "present_position") == 3000


def test_droop_is_proportional_and_halves_when_p_doubles() -> None:
    s = SimServo(2, position=2048, gravity=SO101_SHOULDER_GRAVITY)
    errors = {}
    for p in (16, 32, 64, 128):
        s.set("p_coefficient", p)
        wr(s, "torque_enable", 0)
        wr(s, "goal_position", 2048)
        wr(s, "torque_enable", 1)
        s.step(1.0)
        errors[p] = 2048 - rd(s, "present_position")
        assert rd(s, "present_load") == pytest.approx(SO101_SHOULDER_GRAVITY, abs=1)
    # The seed's Kp sweep: 0.068 rad at Kp 16, and Kp x error constant.
    assert errors[16] * RAD_PER_COUNT == pytest.approx(0.068, abs=0.002)
    for p in (32, 64, 128):
        assert errors[p] == pytest.approx(errors[16] * 16 / p, abs=1)
    assert round(DROOP_K * SO101_SHOULDER_GRAVITY / 16) == 44


def test_limp_holds_nothing() -> None:
    s = SimServo(1, position=1000)
    wr(s, "goal_position", 3000)
    s.step(2)
    assert rd(s, "present_position") == 1000  # torque off: goals are not obeyed
    s.move_by_hand(1500)
    s.step(1)
    assert rd(s, "present_position") == 1500
    assert rd(s, "present_load") == 0 and rd(s, "present_speed") == 0


def test_limp_joint_sags_to_its_rest() -> None:
    s = SimServo(1, position=2000, gravity=100, sag_rate=400, min_limit=900, max_limit=3100)
    s.step(1.0)
    assert rd(s, "present_position") == pytest.approx(1600, abs=2)
    assert rd(s, "present_speed") == -400
    s.step(5)
    assert rd(s, "present_position") == 900  # the stop on gravity's side
    s2 = SimServo(1, position=2000, gravity=100, sag_rate=400, rest=1800)
    s2.step(5)
    assert rd(s2, "present_position") == 1800


def test_enabling_torque_drives_to_the_goal_register() -> None:
    # Why the daemon seeds the goal before enabling: the servo drives to a stale goal.
    s = SimServo(1, position=1000)
    s.move_by_hand(1400)
    wr(s, "torque_enable", 1)
    s.step(1)
    assert rd(s, "present_position") == 1000
    s2 = SimServo(1, position=1000)
    s2.move_by_hand(1400)
    wr(s2, "goal_position", rd(s2, "present_position"))
    wr(s2, "torque_enable", 1)
    s2.step(1)
    assert rd(s2, "present_position") == 1400


def test_recentre_makes_here_read_2048() -> None:
    s = SimServo(1, position=700)
    wr(s, "torque_enable", 128)  # works with EEPROM locked: the servo writes it itself
    assert rd(s, "present_position") == 2048
    assert rd(s, "homing_offset") == 700 - 2048
    assert rd(s, "torque_enable") == 0
    assert s.actual == 700


def test_homing_offset_frame() -> None:
    s = SimServo(1, position=100)
    wr(s, "lock", 0)
    wr(s, "homing_offset", 300)  # present = actual - offset, mod 4096
    assert rd(s, "present_position") == (100 - 300) % 4096
    wr(s, "homing_offset", -500)
    reg = REG["homing_offset"]
    assert s.memory[reg.address : reg.address + 2] == (500 | 1 << 11).to_bytes(2, "little")
    assert rd(s, "present_position") == 600
    wr(s, "goal_position", 1000)  # goals are in the present frame
    wr(s, "torque_enable", 1)
    s.step(1)
    assert rd(s, "present_position") == 1000 and s.actual == pytest.approx(500)


def test_velocity_mode_spins_and_wraps() -> None:
    s = SimServo(7, mode=ct.OperatingMode.VELOCITY, position=100)
    wr(s, "goal_speed", -300)
    s.step(1)
    assert rd(s, "present_position") == 100  # torque off: no spin
    wr(s, "torque_enable", 1)
    s.step(1)
    assert rd(s, "present_position") == (100 - 300) % 4096
    assert rd(s, "present_speed") == -300
    reg = REG["present_speed"]
    assert s.read(reg.address, 2) == (300 | 1 << 15).to_bytes(2, "little")
    assert rd(s, "moving") == 1 and rd(s, "present_load") < 0
    wr(s, "goal_speed", 0)
    s.step(0.1)
    assert rd(s, "present_speed") == 0


def test_goal_outside_limits_is_clamped_by_the_servo() -> None:
    s = holding(2000, min_limit=1000, max_limit=3000)
    wr(s, "goal_position", 3500)
    s.step(2)
    assert rd(s, "present_position") == 3000
    assert rd(s, "goal_position") == 3500  # the register keeps what was written


def test_holding_a_heavy_load_overheats_and_unloads() -> None:
    s = holding(2048, gravity=600)
    for _ in range(60):  # 60 s: warm but not yet over 70 °C
        s.step(1)
    assert s.torque and 27 < rd(s, "present_temperature") <= 70
    for _ in range(300):
        s.step(1)
        if not s.torque:
            break
    assert not s.torque and rd(s, "torque_enable") == 0
    assert s.error & ServoError.OVERHEAT
    assert rd(s, "status") & ServoError.OVERHEAT
    assert rd(s, "present_load") == 0  # unloaded: limp
    s.step(600)  # cools down
    assert rd(s, "present_temperature") < 40
    assert s.error == ServoError.OVERHEAT  # the cause stays readable until re-enabled
    wr(s, "torque_enable", 1)
    s.step(1)
    assert s.torque and s.error == 0


def test_persistent_overload_unloads_and_reenable_reloads() -> None:
    s = holding(2048, gravity=900)  # above the 80 % overload torque
    s.step(1.5)
    assert s.torque
    s.step(1.0)  # past the 2 s protection time
    assert not s.torque and s.error == ServoError.OVERLOAD
    wr(s, "torque_enable", 1)  # the runbook: set_enable true re-loads, no power-cycle
    assert s.torque and s.error == 0


def test_latching_trip_ignores_commands_but_still_reads() -> None:
    s = holding(2048, gravity=900)
    s.trip = "latch"
    s.step(3)
    assert s.latched and s.error & ServoError.OVERLOAD
    wr(s, "torque_enable", 0)
    wr(s, "goal_position", 100)
    s.step(1)
    assert s.torque and rd(s, "goal_position") == 2048  # commands ignored
    assert 1800 < rd(s, "present_position") < 2048  # readback still works (drooping)
    s.power_cycle()  # only a hard power-cycle clears a latch
    assert not s.latched and not s.torque and s.error == 0


def test_latch_fault_mode() -> None:
    s = SimServo(1, position=500)
    s.latch()
    wr(s, "torque_enable", 1)
    s.reg_write(REG["goal_position"].address, b"\x00\x00")
    s.action()
    assert not s.torque and rd(s, "goal_position") == 500
    assert rd(s, "present_position") == 500


def test_eeprom_writes_need_the_lock_open() -> None:
    s = SimServo(1)
    wr(s, "p_coefficient", 64)
    wr(s, "id", 9)
    assert rd(s, "p_coefficient") == 32 and s.id == 1  # locked: ignored
    wr(s, "acceleration", 5)
    assert rd(s, "acceleration") == 5  # RAM is not locked
    wr(s, "lock", 0)
    wr(s, "p_coefficient", 64)
    assert rd(s, "p_coefficient") == 64
    wr(s, "lock", 1)
    wr(s, "p_coefficient", 16)
    assert rd(s, "p_coefficient") == 64


def test_read_only_registers_ignore_writes() -> None:
    s = SimServo(1, position=1000)
    wr(s, "lock", 0)
    for name, value in (("present_position", 5), ("model", 1), ("present_temperature", 99)):
        wr(s, name, value)
    assert rd(s, "present_position") == 1000 and rd(s, "model") == 777
    assert rd(s, "present_temperature") == 27
    # A write spanning read-only and writable bytes applies only the writable ones.
    s.write(REG["torque_limit"].address, bytes([100, 0, 0, 0, 0, 0, 0, 1, 9, 9]))
    assert rd(s, "torque_limit") == 100 and rd(s, "lock") == 1
    assert rd(s, "present_position") == 1000


def test_forced_error_bits() -> None:
    s = SimServo(1)
    s.force_error(ServoError.VOLTAGE | ServoError.ANGLE)
    assert s.error == ServoError.VOLTAGE | ServoError.ANGLE
    s.force_error(0)
    assert s.error == 0


def test_reads_past_the_table_are_zero_padded() -> None:
    assert SimServo(1).read(250, 10) == bytes(10)


def test_rejects_unknown_trip() -> None:
    with pytest.raises(ValueError, match="trip"):
        SimServo(1, trip="explode")
