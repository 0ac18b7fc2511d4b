"""``lupin gains`` end to end: show, apply (double read-back), and the sweep with its guards."""

from __future__ import annotations

import asyncio
import itertools
import json
from pathlib import Path
from typing import Any

import pytest
from benchkit import MakeSim, StartTool

from lupin.bench.gains import ServoGains, write_gains
from lupin.bench.registers import ServoIO
from lupin.bench.session import open_bench_bus
from lupin.protocol import Instruction, status


def sweep_record(home: Path) -> dict[str, Any]:
    (path,) = (home / "arm_gain_sweeps").glob("*.json")
    data: dict[str, Any] = json.loads(path.read_text())
    return data


async def test_show_and_apply(make_sim: MakeSim, tools: StartTool) -> None:
    sim = await make_sim(p_gain={2: 16})  # a servo swap reverted one joint to P=16
    show = tools("gains", "show", "--bus-port", sim.path)
    assert await show.wait() == 1
    assert "shoulder_lift    2  P=16 D=32 I=0    P=32 D=32 I=0     differs" in show.output

    apply = tools("gains", "apply", "--bus-port", sim.path)
    await apply.expect("shoulder_lift (id 2): P=16 D=32 I=0 -> P=32 D=32 I=0")
    await apply.expect("Write these gains? [y/N]")
    assert not sim.bus.writes_to(21)
    apply.send("y\n")
    assert await apply.wait() == 0, apply.output
    assert "shoulder_lift (id 2) P=32 D=32 I=0: ok" in apply.output
    assert sim.bus.servo(2).get("p_coefficient") == 32
    assert {w.id for w in sim.bus.writes_to(21)} == {2}  # only the servo that differed

    again = tools("gains", "show", "--bus-port", sim.path)
    assert await again.wait() == 0


async def test_apply_trusts_only_two_agreeing_read_backs(
    make_sim: MakeSim, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The seed's race: the first read-back after the relock comes back garbled (250)."""
    sim = await make_sim()
    respond = sim.bus.respond
    garble = {"armed": False}

    def racy(packet, now):  # type: ignore[no-untyped-def]
        if packet.code == Instruction.WRITE and packet.params[:2] == bytes([55, 1]):
            garble["armed"] = True
        replies = respond(packet, now)
        if garble["armed"] and packet.code == Instruction.READ and packet.params[0] == 21:
            garble["armed"] = False
            # A well-formed reply holding the wrong value: only a second read exposes it.
            return [r._replace(data=status(packet.id, 0, bytes([250, 32, 0]))) for r in replies]
        return replies

    monkeypatch.setattr(sim.bus, "respond", racy)
    async with open_bench_bus(sim.profile, sim.path) as bus:
        got = await write_gains(ServoIO(bus), 3, ServoGains(64, 32, 0))
    assert got == ServoGains(64, 32, 0)
    reads = [p for _, p in sim.bus.instructions(Instruction.READ) if p.params[0] == 21]
    assert len(reads) == 3  # 250, 64, 64: the garbled one was not trusted


async def test_apply_reports_failed_when_the_read_backs_never_agree(
    make_sim: MakeSim, tools: StartTool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A servo whose gain read-backs keep changing is never reported as written."""
    sim = await make_sim(p_gain={2: 16})
    respond = sim.bus.respond
    noise = itertools.count(200)

    def flaky(packet, now):  # type: ignore[no-untyped-def]
        replies = respond(packet, now)
        gain_read = packet.code == Instruction.READ and packet.id == 2 and packet.params[0] == 21
        if gain_read and sim.bus.servo(2).get("p_coefficient") == 32:  # once the write landed
            value = next(noise) % 256
            return [r._replace(data=status(2, 0, bytes([value, 32, 0]))) for r in replies]
        return replies

    monkeypatch.setattr(sim.bus, "respond", flaky)
    apply = tools("gains", "apply", "--bus-port", sim.path, "--yes")
    assert await apply.wait() == 1, apply.output
    assert "shoulder_lift (id 2) P=32 D=32 I=0: FAILED" in apply.output
    assert "no two read-backs agreed" in apply.output
    assert ": ok" not in apply.output


async def test_sweep_finds_the_droop_law(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    sim = await make_sim()
    tool = tools(
        "gains", "sweep", "--joint", "shoulder_lift", "--kp", "16,32,64,128",
        "--hold", "0.6", "--bus-port", sim.path, "--yes",
    )  # fmt: skip
    assert await tool.wait(60) == 0, tool.output
    assert "droop: error fell" in tool.output
    record = sweep_record(lupin_home)
    scores = [t["score"] for t in record["trials"]]
    assert [s["kp"] for s in scores] == [16, 32, 64, 128]
    errors = [s["error_rad"] for s in scores]
    # Error roughly halves each time Kp doubles, and Kp × error holds.
    for a, b in itertools.pairwise(errors):
        assert 1.5 < a / b < 2.6, errors
    products = [s["kp_error"] for s in scores]
    assert max(products) / min(products) < 1.3, products
    assert all(s["load"] < 900 for s in scores)  # droop, not saturation
    assert all(len(t["samples"]) > 30 for t in record["trials"])  # 50 Hz over 0.6 s + rest
    # Guards: only the swept joint was torqued; it ends limp on its original gains.
    assert {w.id for w in sim.bus.writes_to(40)} == {2}
    servo = sim.bus.servo(2)
    assert not servo.torque and servo.get("p_coefficient") == 32
    assert abs(servo.present_position - record["rest_counts"]) <= 10


async def test_sweep_refuses_a_step_past_the_soft_limit(
    make_sim: MakeSim, tools: StartTool
) -> None:
    sim = await make_sim()
    tool = tools("gains", "sweep", "--joint", "elbow_flex", "--step", "-2.0",
                 "--bus-port", sim.path, "--yes")  # fmt: skip
    assert await tool.wait() == 1
    assert "outside elbow_flex's soft limits 1024..3072" in tool.output
    assert not sim.bus.writes()


async def test_sweep_asks_to_release_other_joints(make_sim: MakeSim, tools: StartTool) -> None:
    sim = await make_sim()
    sim.bus.servo(4).set("torque_enable", 1)
    tool = tools("gains", "sweep", "--joint", "elbow_flex", "--bus-port", sim.path)
    await tool.expect("Release torque on wrist_flex? (support the arm) [y/N]")
    tool.send("n\n")
    assert await tool.wait() == 1
    assert sim.bus.servo(4).torque and not sim.bus.writes()


async def test_ctrl_c_restores_gains_and_drops_torque(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    sim = await make_sim()
    tool = tools("gains", "sweep", "--joint", "elbow_flex", "--kp", "16,32,64,128",
                 "--hold", "5", "--bus-port", sim.path, "--yes")  # fmt: skip
    await tool.expect("Kp  Ki")
    servo = sim.bus.servo(3)
    # Wait until the first trial holds its step under P=16, then interrupt.
    for _ in range(200):
        if servo.torque and servo.get("p_coefficient") == 16 and servo.present_position < 1950:
            break
        await asyncio.sleep(0.02)
    assert servo.torque and servo.get("p_coefficient") == 16
    tool.interrupt()
    assert await tool.wait() == 130, tool.output
    assert "restored and verified" in tool.output and "torque off" in tool.output
    assert servo.get("p_coefficient") == 32 and not servo.torque
    # Back where it started, short by the droop of the gain it returned under (P=16: 22 counts).
    assert abs(servo.present_position - 2048) <= 60 * 5.9 / 16 + 2
    record = sweep_record(lupin_home)
    assert record["stopped"] == "interrupted"
    assert record["cleanup"]["gains_restored"] and record["cleanup"]["torque_off"]
    assert "Traceback" not in tool.output


async def test_sweep_stops_at_max_temp(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    sim = await make_sim()
    tool = tools("gains", "sweep", "--joint", "elbow_flex", "--kp", "16,32",
                 "--hold", "3", "--bus-port", sim.path, "--yes")  # fmt: skip
    await tool.expect("Kp  Ki")
    sim.bus.servo(3).physics.temperature = 58.0
    assert await tool.wait() == 1, tool.output
    assert "Stopped: elbow_flex reached 58 °C (--max-temp 55 °C)" in tool.output
    servo = sim.bus.servo(3)
    assert servo.get("p_coefficient") == 32 and not servo.torque
