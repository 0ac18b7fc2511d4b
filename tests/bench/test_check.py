"""``lupin check`` end to end on a pty: enumeration, health, strays, zero snapshot, port guard."""

from __future__ import annotations

import asyncio
import os
import sys
from pathlib import Path

from benchkit import MakeSim, StartTool

from lupin.protocol import Instruction


async def test_every_servo_answers(make_sim: MakeSim, tools: StartTool) -> None:
    sim = await make_sim(positions={3: 2148}, extra_ids=[12])
    sim.bus.servo(3).set("present_voltage", 52)
    tool = tools("check", "--bus-port", sim.path)
    assert await tool.wait() == 0, tool.output
    out = tool.output
    assert "8 of 8 profile servos answer." in out
    assert "strays (ids 0-20 not in the profile): 12" in out
    # Health per servo: firmware, model, mode, torque, voltage, temperature, load.
    row = next(line for line in out.splitlines() if "elbow_flex" in line and "arm" in line)
    assert row.split()[3:10] == ["3.10", "777", "0", "off", "5.2V", "27C", "0"]
    # The zero snapshot, in counts and radians about the zero (2048 in the profile).
    assert "elbow_flex      2148 counts  +0.1534 rad" in out
    # Read-only: nothing but pings and reads went out.
    assert not sim.bus.writes()
    assert not sim.bus.instructions(Instruction.SYNC_WRITE)


async def test_a_silent_servo_fails_the_check(make_sim: MakeSim, tools: StartTool) -> None:
    sim = await make_sim()
    sim.bus.kill(5)
    tool = tools("check", "--bus-port", sim.path, "--scan", "0-3")
    assert await tool.wait() == 1
    assert "no reply from: wrist_roll (id 5)" in tool.output
    assert "7 of 8 profile servos answer." in tool.output


async def test_refuses_a_port_another_process_holds(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    sim = await make_sim()
    holder = await asyncio.create_subprocess_exec(
        sys.executable,
        "-c",
        "import os, sys, time; fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY); "
        "print('holding', flush=True); time.sleep(60)",
        sim.path,
        stdout=asyncio.subprocess.PIPE,
    )
    try:
        assert holder.stdout is not None
        assert await holder.stdout.readline() == b"holding\n"
        for argv in (["check"], ["calibrate", "--yes"], ["offsets", "show"], ["gains", "show"]):
            tool = tools(*argv, "--bus-port", sim.path)
            assert await tool.wait() == 4, tool.output
            assert f"PID {holder.pid}" in tool.output
        assert not sim.bus.received  # refused before a single byte was sent
    finally:
        holder.kill()
        await holder.wait()


async def test_refuses_while_the_daemon_runs(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    sim = await make_sim()
    env = dict(os.environ, LUPIN_HOME=str(lupin_home))
    daemon = await asyncio.create_subprocess_exec(
        sys.executable,
        *("-m", "lupin", "run", "--bus-port", sim.path, "--port", "0"),
        stdout=asyncio.subprocess.DEVNULL,
        stderr=asyncio.subprocess.PIPE,
        env=env,
    )
    try:
        assert daemon.stderr is not None
        async with asyncio.timeout(20):
            while b"ready:" not in await daemon.stderr.readline():
                pass
        tool = tools("check", "--bus-port", sim.path)
        assert await tool.wait() == 4
        assert f"PID {daemon.pid}" in tool.output
    finally:
        if daemon.returncode is None:
            daemon.terminate()
        await daemon.wait()
