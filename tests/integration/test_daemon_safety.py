"""The daemon's safety properties, proven by the packets the simulated servos received."""

from __future__ import annotations

import asyncio
import itertools
import time

from lupin import control_table as ct
from lupin.arm import Refused, Torque
from lupin.daemon import Daemon
from lupin.mux import Twist
from lupin.protocol import Instruction
from lupintest.harness import Sim, wait_for

TORQUE = ct.REGISTERS["torque_enable"].address
GOAL_POS = ct.REGISTERS["goal_position"].address
GOAL_SPEED = ct.REGISTERS["goal_speed"].address
ARM_IDS = [1, 2, 3, 4, 5, 6]
WHEELS = [7, 9]


async def enable_torque(daemon: Daemon) -> None:
    await daemon.enable_torque()
    await wait_for(lambda: daemon.arm.gate_open, timeout=3.0)


def wheel_speeds_written(sim: Sim, since: float) -> list[tuple[float, int, int]]:
    return [
        (w.t, w.id, v)
        for w in sim.bus.writes_to(GOAL_SPEED, since=since)
        if w.id in WHEELS and (v := w.value("goal_speed")) is not None
    ]


async def test_boot_is_limp_and_idle_writes_nothing(sim: Sim, daemon: Daemon) -> None:
    await asyncio.sleep(0.5)
    # No torque write at boot, and no write of any kind while idle.
    assert sim.bus.writes_to(TORQUE) == []
    assert sim.all_writes() == []
    # Meanwhile every servo was read every tick (8 ids in one SYNC_READ).
    reads = sim.packets(Instruction.SYNC_READ)
    assert len(reads) > 20
    assert set(reads[-1][1].params[2:]) == {*ARM_IDS, *WHEELS}
    assert all(not sim.bus.servo(i).torque for i in ARM_IDS + WHEELS)
    assert daemon.arm.torque_summary is Torque.OFF


async def test_commands_refused_while_limp(daemon: Daemon) -> None:
    now = time.monotonic()
    try:
        daemon.arm.move({"elbow_flex": 0.3}, 1.0, now)
    except Refused as exc:
        assert exc.code == "torque_off"
    else:
        raise AssertionError("a move was accepted with torque off")


async def test_enable_seeds_goal_before_torque_and_sagged_arm_does_not_jump(
    sim: Sim, daemon: Daemon
) -> None:
    # Sag the limp arm by hand, away from the (stale) power-up goal registers.
    for sid in ARM_IDS:
        sim.bus.servo(sid).move_by_hand(2048 + 150)
    await asyncio.sleep(0.1)
    before = {sid: sim.bus.servo(sid).present_position for sid in ARM_IDS}
    t0 = time.monotonic()
    await enable_torque(daemon)
    await asyncio.sleep(0.3)
    for sid in ARM_IDS:
        goal = sim.bus.writes_to(GOAL_POS, since=t0, id=sid)
        torque = sim.bus.writes_to(TORQUE, since=t0, id=sid)
        assert goal and torque, f"servo {sid}: no goal seed or no torque write"
        assert goal[0].t < torque[0].t, f"servo {sid}: torque went on before the goal was seeded"
        assert goal[0].value("goal_position") == before[sid]
        assert torque[0].value("torque_enable") == 1
        # No jump: the servo holds where the hand left it (droop aside).
        assert abs(sim.bus.servo(sid).present_position - before[sid]) < 30
    # One joint per tick: the torque writes are spread over distinct ticks.
    torque_times = sorted(sim.bus.writes_to(TORQUE, since=t0)[i].t for i in range(6))
    assert all(b - a > 0.004 for a, b in itertools.pairwise(torque_times))


async def test_motion_is_one_sync_write_per_tick_and_stops_when_done(
    sim: Sim, daemon: Daemon
) -> None:
    await enable_torque(daemon)
    await asyncio.sleep(0.2)
    t0 = time.monotonic()
    daemon.arm.move({"elbow_flex": 0.5, "wrist_flex": -0.3}, 0.6, t0)
    await asyncio.sleep(0.8)
    t1 = time.monotonic()
    writes = sim.packets(Instruction.SYNC_WRITE, since=t0)
    reads = sim.sync_reads(since=t0)
    assert len(writes) >= 30, "the move produced too few goal updates"
    # Never more than one SYNC_WRITE between two SYNC_READs (one per tick).
    bounds = [*reads, t1]
    for a, b in itertools.pairwise(bounds):
        assert sum(1 for t, _ in writes if a <= t < b) <= 1
    assert sim.packets(Instruction.WRITE, since=t0) == []
    # The joint arrived (within droop) and, once there, the bus goes quiet.
    elbow = daemon.geometry["elbow_flex"]
    assert abs(elbow.counts_to_rad(sim.bus.servo(3).present_position) - 0.5) < 0.06
    await asyncio.sleep(0.2)
    quiet_from = time.monotonic()
    await asyncio.sleep(0.3)
    assert sim.all_writes(since=quiet_from) == []


async def test_estop_zeroes_wheels_within_one_tick(sim: Sim, daemon: Daemon) -> None:
    async def drive() -> None:
        while True:
            daemon.submit_twist("manual", Twist(linear_x=0.1))
            await asyncio.sleep(0.05)

    driver = asyncio.create_task(drive())
    try:
        await wait_for(lambda: abs(sim.bus.servo(7).get("goal_speed")) > 0)
        await asyncio.sleep(0.1)
        t_e = time.monotonic()
        await daemon.set_estop(True)
        await wait_for(lambda: wheel_speeds_written(sim, t_e))
        zero_at = min(t for t, _, v in wheel_speeds_written(sim, t_e) if v == 0)
        reads_after = sim.sync_reads(since=t_e)
        # The zero went out in the first tick after the E-stop, before the next read.
        assert len([t for t in reads_after if t < zero_at]) <= 1
        await asyncio.sleep(0.3)
        # Still zero while the commander keeps sending: the E-stop masks every source.
        assert all(v == 0 for _, _, v in wheel_speeds_written(sim, zero_at))
        assert sim.bus.servo(7).get("goal_speed") == 0
    finally:
        driver.cancel()


async def test_silent_commander_stops_wheels_within_timeout(sim: Sim, daemon: Daemon) -> None:
    daemon.submit_twist("manual", Twist(linear_x=0.1))
    t_cmd = time.monotonic()
    await wait_for(lambda: sim.bus.servo(7).get("goal_speed") != 0)
    await wait_for(lambda: sim.bus.servo(7).get("goal_speed") == 0, timeout=2.0)
    written = wheel_speeds_written(sim, t_cmd)
    moving_at = min(t for t, _, v in written if v != 0)
    stopped = [t for t, _, v in written if v == 0 and t > moving_at]
    timeout = sim.profile.base.command_timeout_s if sim.profile.base else 0.5
    # Within the source's timeout plus one tick (and scheduling slack).
    assert stopped[0] - t_cmd <= timeout + 0.01 + 0.05
    assert stopped[0] - t_cmd >= timeout - 0.02


async def test_excluded_servo_in_wrong_mode(sim: Sim) -> None:
    from lupin.daemon import Daemon, DaemonOptions

    sim.bus.servo(3).set("operating_mode", 1)
    d = Daemon(sim.profile, DaemonOptions(bus_port=sim.path, auto_home=False))
    await d.start()
    try:
        assert await d.wait_ready(3.0)
        assert "operating mode reads 1" in d.arm.excluded["elbow_flex"]
        t0 = time.monotonic()
        await d.enable_torque()
        await wait_for(lambda: d.arm.gate_open)
        await asyncio.sleep(0.2)
        assert sim.bus.writes_to(GOAL_POS, since=t0, id=3) == []
        assert sim.bus.writes_to(TORQUE, since=t0, id=3) == []
    finally:
        await d.stop()
