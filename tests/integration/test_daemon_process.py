"""``lupin run`` as a real process: start-up, refusal, and the shutdown sequence on a signal."""

from __future__ import annotations

import asyncio
import signal
import time
from pathlib import Path

from lupin import control_table as ct
from lupintest.harness import Sim, child_env, lupin_cmd

TORQUE = ct.REGISTERS["torque_enable"].address
GOAL_SPEED = ct.REGISTERS["goal_speed"].address


async def spawn(home: Path, *args: str) -> asyncio.subprocess.Process:
    return await asyncio.create_subprocess_exec(
        *lupin_cmd("run", "--port", "0", *args),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        env=child_env(home),
    )


async def read_until(proc: asyncio.subprocess.Process, needle: str, timeout: float = 10.0) -> str:
    assert proc.stderr is not None
    seen = []
    async with asyncio.timeout(timeout):
        while True:
            line = (await proc.stderr.readline()).decode()
            if not line:
                raise AssertionError(f"process ended before {needle!r}: {''.join(seen)}")
            seen.append(line)
            if needle in line:
                return "".join(seen)


async def test_sigterm_zeroes_wheels_limps_arm_and_exits_zero(sim: Sim, lupin_home: Path) -> None:
    proc = await spawn(lupin_home, "--bus-port", sim.path)
    try:
        await read_until(proc, "ready:")
        # Put torque on every servo behind the daemon's back, and spin a wheel,
        # so the shutdown sequence has something to undo.
        for sid in [1, 2, 3, 4, 5, 6, 7, 9]:
            sim.bus.servo(sid).set("torque_enable", 1)
        sim.bus.servo(7).set("goal_speed", 500)
        t_sig = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        async with asyncio.timeout(1.0):
            code = await proc.wait()
        elapsed = time.monotonic() - t_sig
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    assert code == 0
    assert elapsed < 1.0
    speeds = {w.id: w.value("goal_speed") for w in sim.bus.writes_to(GOAL_SPEED, since=t_sig)}
    assert speeds == {7: 0, 9: 0}
    limp = {w.id for w in sim.bus.writes_to(TORQUE, since=t_sig) if w.value("torque_enable") == 0}
    assert limp == {1, 2, 3, 4, 5, 6, 7, 9}
    assert all(not sim.bus.servo(i).torque for i in [1, 2, 3, 4, 5, 6, 7, 9])
    # The port is released: nobody holds the pty for writing any more.
    from lupin_adapters.serial_link import port_holders

    assert port_holders(sim.path) == []


async def test_bus_that_cannot_open_fails_clearly(lupin_home: Path) -> None:
    proc = await spawn(lupin_home, "--bus-port", "/dev/does-not-exist")
    async with asyncio.timeout(10):
        _, err = await proc.communicate()
    assert proc.returncode == 4
    assert b"cannot open the servo bus" in err and b"/dev/does-not-exist" in err


async def test_second_daemon_on_the_same_bus_is_refused_naming_the_first(
    sim: Sim, lupin_home: Path
) -> None:
    first = await spawn(lupin_home, "--bus-port", sim.path)
    try:
        await read_until(first, "ready:")
        t0 = time.monotonic()
        second = await spawn(lupin_home, "--bus-port", sim.path)
        async with asyncio.timeout(10):
            _, err = await second.communicate()
        assert second.returncode == 4
        assert f"PID {first.pid}".encode() in err
        # The loser sent nothing: every packet since it started came from the first daemon
        # (reads only; the first daemon is idle and writes nothing).
        assert sim.all_writes(since=t0) == []
    finally:
        first.send_signal(signal.SIGTERM)
        await first.wait()


async def test_run_sim_needs_no_setup(lupin_home: Path) -> None:
    proc = await spawn(lupin_home, "--sim")
    try:
        out = await read_until(proc, "ready:")
        assert "so101 on simulated bus, arm limp" in out
        proc.send_signal(signal.SIGINT)
        async with asyncio.timeout(2):
            assert await proc.wait() == 0
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
