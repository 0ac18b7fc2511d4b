"""The ExecStopPost helper: a daemon killed mid-motion leaves no servo energised.

The SIGKILL test kills a real ``lupin run`` while auto-home is driving the arm
(and, behind its back, both wheels spin), then runs ``lupin stop-helper`` as
systemd would, and judges by the simulated servos' registers and packet log.
"""

from __future__ import annotations

import asyncio
import signal
import time
from pathlib import Path

import pytest

from lupin import control_table as ct
from lupin.config import load_profile
from lupin.protocol import Instruction
from lupin.stop_helper import StopReport, clean_exit, limp_all, run_stop_helper
from lupintest.harness import Sim, child_env, lupin_cmd, wait_for

TORQUE = ct.REGISTERS["torque_enable"].address
GOAL_POS = ct.REGISTERS["goal_position"].address
GOAL_SPEED = ct.REGISTERS["goal_speed"].address
ARM = [1, 2, 3, 4, 5, 6]
WHEELS = [7, 9]
ALL = ARM + WHEELS
# What systemd hands ExecStopPost after a SIGKILL of the main process.
KILLED = {"SERVICE_RESULT": "signal", "EXIT_CODE": "killed", "EXIT_STATUS": "KILL"}
CLEAN = {"SERVICE_RESULT": "success", "EXIT_CODE": "exited", "EXIT_STATUS": "0"}


async def spawn(args: list[str], env: dict[str, str]) -> asyncio.subprocess.Process:
    return await asyncio.create_subprocess_exec(
        *lupin_cmd(*args), stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE, env=env
    )


async def read_until(proc: asyncio.subprocess.Process, needle: str, timeout: float = 15.0) -> None:
    assert proc.stderr is not None
    seen = []
    async with asyncio.timeout(timeout):
        while True:
            line = (await proc.stderr.readline()).decode()
            if not line:
                raise AssertionError(f"process ended before {needle!r}: {''.join(seen)}")
            seen.append(line)
            if needle in line:
                return


async def stop_helper(sim: Sim, home: Path, env_extra: dict[str, str]) -> tuple[int, str, float]:
    env = child_env(home) | env_extra
    t0 = time.monotonic()
    proc = await spawn(["stop-helper", "--bus-port", sim.path], env)
    async with asyncio.timeout(10):
        _, err = await proc.communicate()
    assert proc.returncode is not None
    return proc.returncode, err.decode(), time.monotonic() - t0


def limp_writes(sim: Sim, since: float) -> list[tuple[float, int]]:
    return [
        (w.t, w.id) for w in sim.bus.writes_to(TORQUE, since=since) if w.value("torque_enable") == 0
    ]


async def test_sigkill_mid_motion_then_helper_limps_everything(sim: Sim, lupin_home: Path) -> None:
    env = child_env(lupin_home) | {"LUPIN_AUTO_HOME": "true"}
    daemon = await spawn(["run", "--port", "0", "--bus-port", sim.path], env)
    try:
        await read_until(daemon, "ready:")
        # Auto-home energises the arm and drives it to `home` over 3 s: wait until
        # it is really moving, goals streaming, then pull the plug.
        await wait_for(lambda: all(sim.bus.servo(i).torque for i in ARM), timeout=10.0)
        t_move = time.monotonic()
        await wait_for(lambda: sim.bus.writes_to(GOAL_POS, since=t_move), timeout=2.0)
        for wheel, speed in zip(WHEELS, (600, -600), strict=True):  # a drive in progress
            sim.bus.servo(wheel).set("torque_enable", 1)
            sim.bus.servo(wheel).set("goal_speed", speed)
        daemon.send_signal(signal.SIGKILL)
        async with asyncio.timeout(5):
            await daemon.wait()
    finally:
        if daemon.returncode is None:
            daemon.kill()
            await daemon.wait()
    assert daemon.returncode == -signal.SIGKILL
    # The kill skipped the daemon's own safe stop: everything is still energised.
    assert all(sim.bus.servo(i).torque for i in ALL)
    assert [sim.bus.servo(w).get("goal_speed") for w in WHEELS] == [600, -600]

    t_helper = time.monotonic()
    code, err, elapsed = await stop_helper(sim, lupin_home, KILLED)
    assert code == 0, err
    assert elapsed < 5.0  # inside TimeoutStopSec, interpreter start-up included
    assert not any(sim.bus.servo(i).torque for i in ALL)
    assert [sim.bus.servo(w).get("goal_speed") for w in WHEELS] == [0, 0]
    # Each command went out twice as one broadcast to every servo (wheels: zero speed
    # first), and nothing else was written: no goal position, no torque on.
    syncs = [p for _, p in sim.packets(Instruction.SYNC_WRITE, since=t_helper)]
    kinds = [(p.params[0], sorted(p.params[2:][:: p.params[1] + 1])) for p in syncs]
    assert kinds == [(GOAL_SPEED, WHEELS), (TORQUE, ALL)] * 2
    assert {sid for _, sid in limp_writes(sim, t_helper)} == set(ALL)
    assert sim.bus.writes_to(GOAL_POS, since=t_helper) == []
    assert "signal" in err and "limped" in err and "read back off" in err


async def test_clean_exit_is_skipped_without_touching_the_bus(sim: Sim, lupin_home: Path) -> None:
    for i in ALL:  # would be limped if the helper acted
        sim.bus.servo(i).set("torque_enable", 1)
    t0 = time.monotonic()
    code, err, _ = await stop_helper(sim, lupin_home, CLEAN)
    assert code == 0
    assert "exited cleanly" in err
    assert [p for t, p in sim.bus.received if t >= t0] == []
    assert all(sim.bus.servo(i).torque for i in ALL)


async def test_a_live_owner_of_the_bus_is_left_alone_and_named(sim: Sim, lupin_home: Path) -> None:
    daemon = await spawn(["run", "--port", "0", "--bus-port", sim.path], child_env(lupin_home))
    try:
        await read_until(daemon, "ready:")
        t0 = time.monotonic()
        code, err, _ = await stop_helper(sim, lupin_home, KILLED)
        assert code == 0  # never fails the unit's stop
        assert f"PID {daemon.pid}" in err and "refused" in err
        assert sim.all_writes(since=t0) == []  # the idle daemon only reads; the helper sent nothing
    finally:
        daemon.send_signal(signal.SIGTERM)
        async with asyncio.timeout(5):
            await daemon.wait()


async def test_a_broken_calibration_file_does_not_stop_the_limp(sim: Sim, lupin_home: Path) -> None:
    (lupin_home / "arm.yaml").write_text("joints: {elbow_flex: {zero: 9999}}\n")
    for i in ALL:
        sim.bus.servo(i).set("torque_enable", 1)
    code, err, _ = await stop_helper(sim, lupin_home, KILLED)
    assert code == 0
    assert "without the calibration overlay" in err and "limped" in err
    assert not any(sim.bus.servo(i).torque for i in ALL)


async def test_a_bad_site_config_is_logged_and_exits_0(sim: Sim, lupin_home: Path) -> None:
    config = lupin_home / "site.yaml"
    config.write_text("bus: {port: 42, nonsense: true}\n")
    env = child_env(lupin_home) | KILLED
    proc = await spawn(["stop-helper", "--config", str(config), "--bus-port", sim.path], env)
    async with asyncio.timeout(10):
        _, err = await proc.communicate()
    assert proc.returncode == 0
    assert b"cannot load the profile" in err and b"nonsense" in err


@pytest.mark.parametrize(
    ("env", "clean"),
    [
        (CLEAN, True),
        (KILLED, False),
        ({}, False),  # by hand: nothing is known, act
        ({"SERVICE_RESULT": "watchdog", "EXIT_CODE": "dumped", "EXIT_STATUS": "ABRT"}, False),
        ({"SERVICE_RESULT": "success", "EXIT_CODE": "killed", "EXIT_STATUS": "TERM"}, False),
        ({"SERVICE_RESULT": "exit-code", "EXIT_CODE": "exited", "EXIT_STATUS": "4"}, False),
    ],
)
def test_clean_exit_reading(env: dict[str, str], clean: bool) -> None:
    assert clean_exit(env) is clean


async def test_silent_and_latched_servos_are_reported_not_waited_for(sim: Sim) -> None:
    for i in ALL:
        sim.bus.servo(i).set("torque_enable", 1)
    sim.bus.kill(5)  # unplugged: no answer
    sim.bus.latch(2)  # the runbook's latched shoulder: ignores commands, still reads
    t0 = time.monotonic()
    report = await asyncio.wait_for(limp_all(sim.profile, sim.path), 2.0)
    assert time.monotonic() - t0 < 1.0
    assert report.action == "limped" and report.rounds == 2
    assert report.silent == [5]
    assert report.still_on == [2]
    assert sorted(report.confirmed_off) == [1, 3, 4, 6, 7, 9]
    assert "STILL ON: [2]" in report.summary() and "no answer: [5]" in report.summary()


async def test_a_missing_port_fails_fast_and_quietly() -> None:
    profile = load_profile("so101")
    report = await run_stop_helper(profile, "/dev/does-not-exist", env=KILLED, timeout=2.0)
    assert report.action == "failed"
    assert "/dev/does-not-exist" in report.reason


async def test_a_hanging_open_is_cut_off_by_the_deadline() -> None:
    async def never_opens(_device: str, _baud: int, **_: object) -> object:
        await asyncio.Event().wait()
        raise AssertionError("unreachable")

    t0 = time.monotonic()
    report = await run_stop_helper(
        load_profile("so101"), "/dev/lupin_servos", env={}, timeout=0.2, opener=never_opens
    )
    assert report == StopReport("timeout", "gave up after 0.2 s on /dev/lupin_servos")
    assert time.monotonic() - t0 < 1.0
