"""``lupin calibrate`` end to end: the tool on a pseudo-terminal, the joints swept by hand.

The test plays the operator: it moves the limp simulated servos (``move_by_hand``)
while the tool samples them at 20 Hz, answers the prompts and presses Enter.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
import yaml
from benchkit import (
    MakeSim,
    Sim,
    StartTool,
    Tool,
    backups,
    lerobot_degrees,
    lupin_degrees,
    ramp,
    sweep_by_hand,
)

from lupin.config import load_profile
from lupin.joints import RAD_PER_COUNT
from lupin.protocol import Instruction

MARGIN = 0.05 / RAD_PER_COUNT  # counts

# Present counts, unwrapped. shoulder_pan straddles 0/4095 (starts at 3900,
# swept 3500..4900, i.e. through 0 to 804): its middle 4200 needs an offset of
# 2152, folded to -1944. The others are plain.
START = {1: 3900.0}
PATHS = {
    1: ramp(3900, 4900, 3500, 4000),
    2: ramp(2048, 1000, 3100, 2048),
    3: ramp(2048, 900, 3000, 2000),
    4: ramp(2048, 1200, 2900),
    5: ramp(2048, 300, 3900),
    6: ramp(2048, 1950, 2850),
}
SWEPT = {1: (3500, 4900), 2: (1000, 3100), 3: (900, 3000), 4: (1200, 2900), 5: (300, 3900),
         6: (1950, 2850)}  # fmt: skip
NAMES = {1: "shoulder_pan", 2: "shoulder_lift", 3: "elbow_flex", 4: "wrist_flex",
         5: "wrist_roll", 6: "gripper"}  # fmt: skip


def expected_offset(lo: int, hi: int) -> int:
    offset = round((lo + hi) / 2) - 2048
    return (offset + 2048) % 4096 - 2048


async def sweep(tool: Tool, sim: Sim, paths: dict[int, list[float]]) -> None:
    await tool.expect("Press Enter")
    await sweep_by_hand(sim.bus, paths)
    tool.send("\n")


def overlay(home: Path) -> dict[str, Any]:
    data: dict[str, Any] = yaml.safe_load((home / "arm.yaml").read_text())
    return data


async def test_full_calibration_with_a_wrapped_joint(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    sim = await make_sim(positions=START)
    tool = tools("calibrate", "--bus-port", sim.path, "--yes")
    await sweep(tool, sim, PATHS)
    assert await tool.wait() == 0, tool.output
    out = tool.output
    assert "crossed 0/4095" in out  # the live table saw the wrap
    assert "shoulder_pan (id 1): homing offset 0 -> -1944" in out  # folded, not refused
    assert "Write these offsets? [y/N] yes (--yes)" in out

    data = overlay(lupin_home)["joints"]
    for sid, (lo, hi) in SWEPT.items():
        name, offset = NAMES[sid], expected_offset(lo, hi)
        servo = sim.bus.servo(sid)
        assert servo.get("homing_offset") == offset, name
        # The middle of the swept range now reads 2048: 0 rad is mid-travel.
        servo.move_by_hand(((lo + hi) / 2 - offset) % 4096)
        assert servo.present_position == 2048, name
        entry = data[name]
        half = (hi - lo) / 2
        assert entry["zero"] == 2048
        assert entry["min"] == math.ceil(2048 - half + MARGIN), name
        assert entry["max"] == math.floor(2048 + half - MARGIN), name
        m = entry["measurement"]
        assert (m["swept_min"], m["swept_max"]) == (2048 - half, 2048 + half)
        assert m["homing_offset"] == offset and m["previous_homing_offset"] == 0
        assert m["margin_rad"] == 0.05 and m["samples"] > 20
        assert m["wrapped"] is (sid == 1)
    # The backup holds the offsets from before the first write.
    backup = yaml.safe_load((lupin_home / "arm_offsets_backup.yaml").read_text())
    assert all(j["homing_offset"] == 0 for j in backup["joints"].values())
    # The daemon's loader accepts the result.
    profile = load_profile("so101", home=lupin_home)
    assert profile.joint("shoulder_pan").zero == 2048
    # The EEPROM was unlocked for the writes and relocked after each.
    assert all(sim.bus.servo(s).get("lock") == 1 for s in NAMES)

    # Exported for LeRobot: the swept stops, and every pose reads the same angle there.
    out = lupin_home / "so101_follower.json"
    export = tools("offsets", "export-lerobot", str(out), "--bus-port", sim.path)
    assert await export.wait() == 0, export.output
    motors = json.loads(out.read_text())
    for sid, (lo, hi) in SWEPT.items():
        name, half = NAMES[sid], (hi - lo) / 2
        motor = motors[name]
        assert (motor["range_min"], motor["range_max"]) == (2048 - half, 2048 + half), name
        assert motor["homing_offset"] == expected_offset(lo, hi)
        for present in (motor["range_min"] + 30, 2048, motor["range_max"] - 30):
            sim.bus.servo(sid).move_by_hand(present)
            p = sim.bus.servo(sid).present_position
            ours, theirs = lupin_degrees(lupin_home, name, p), lerobot_degrees(p, motor)
            assert ours == pytest.approx(theirs, abs=0.1), (name, p, ours, theirs)


async def test_asks_before_torque_and_eeprom_and_migrates_poses(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    sim = await make_sim(positions=START)
    sim.bus.servo(3).set("torque_enable", 1)  # a driver killed outright left it holding
    poses = {"rest": {"shoulder_pan": 0.0, "elbow_flex": 0.2}, "reach": {"elbow_flex": 1.5}}
    (lupin_home / "poses.yaml").write_text(yaml.safe_dump({"poses": poses}))
    before = (lupin_home / "poses.yaml").read_text()

    tool = tools("calibrate", "--bus-port", sim.path)
    await tool.expect("Release torque now? [y/N]")
    assert not sim.bus.writes_to(40)  # nothing released before the answer
    tool.send("y\n")
    await sweep(tool, sim, PATHS)
    await tool.expect("Write these offsets? [y/N]")
    assert not sim.bus.writes_to(31)  # one confirmation, before any EEPROM write
    tool.send("y\n")
    assert await tool.wait() == 0, tool.output

    assert (lupin_home / "poses.yaml.bak").read_text() == before
    migrated = yaml.safe_load((lupin_home / "poses.yaml").read_text())["poses"]
    # Each migrated pose names the same physical position as before.
    for pose, joints in poses.items():
        for joint, old_rad in joints.items():
            sid = next(s for s, n in NAMES.items() if n == joint)
            new_offset = sim.bus.servo(sid).get("homing_offset")
            actual_before = 2048 + old_rad / RAD_PER_COUNT + 0
            actual_after = 2048 + migrated[pose][joint] / RAD_PER_COUNT + new_offset
            assert abs((actual_after - actual_before + 2048) % 4096 - 2048) < 1e-3, joint
    # rest's shoulder_pan (old 0 rad = raw 2048) and reach's elbow are out of reach now.
    assert "Pose 'rest' is now outside shoulder_pan's limits" in tool.output
    assert "Pose 'reach' is now outside elbow_flex's limits" in tool.output
    assert "Pose 'rest' is now outside elbow_flex" not in tool.output


async def test_declining_the_eeprom_write_changes_nothing(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    sim = await make_sim()
    tool = tools("calibrate", "--bus-port", sim.path, "--joints", "elbow_flex")
    await sweep(tool, sim, {3: PATHS[3]})
    await tool.expect("Write these offsets? [y/N]")
    tool.send("n\n")
    assert await tool.wait() == 1
    assert not sim.bus.writes_to(31)
    assert not (lupin_home / "arm.yaml").exists()


@pytest.mark.parametrize(
    ("argv", "paths", "needle"),
    [
        (
            ["--joints", "wrist_roll"],
            {5: ramp(2048, 2048 + 4300, step=200)},
            "wrist_roll: swept 6.60 rad, more than one revolution",
        ),
        (
            ["--joints", "gripper"],
            {6: ramp(2048, 2080, 2048)},
            "gripper: swept only 0.049 rad, too short for the 0.05 rad margin at both ends",
        ),
        (
            ["--joints", "shoulder_pan", "--skip-homing"],
            {1: ramp(3900, 4900, 3500)},
            "shoulder_pan: the sweep crossed the encoder's 0/4095 boundary",
        ),
        (
            ["--joints", "elbow_flex", "--skip-homing"],
            {3: ramp(2048, 2200, 3000)},
            "elbow_flex: the zero (2048 counts) is outside the swept band",
        ),
    ],
    ids=["beyond-one-revolution", "too-short", "wrap-under-skip-homing", "zero-outside-band"],
)
async def test_refusals_write_nothing(
    make_sim: MakeSim,
    tools: StartTool,
    lupin_home: Path,
    argv: list[str],
    paths: dict[int, list[float]],
    needle: str,
) -> None:
    sim = await make_sim(positions=START)
    tool = tools("calibrate", "--bus-port", sim.path, "--yes", *argv)
    await sweep(tool, sim, paths)
    assert await tool.wait() == 1, tool.output
    assert needle in tool.output
    assert "Nothing was written." in tool.output
    assert not sim.bus.writes_to(31) and not sim.bus.writes_to(55)
    assert not (lupin_home / "arm.yaml").exists()


async def test_skip_homing_saves_ranges_and_writes_no_eeprom(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    sim = await make_sim()
    tool = tools("calibrate", "--bus-port", sim.path, "--skip-homing", "--joints", "elbow_flex")
    await sweep(tool, sim, {3: PATHS[3]})
    assert await tool.wait() == 0, tool.output
    assert "Write these offsets?" not in tool.output
    assert not sim.bus.writes_to(31)
    entry = overlay(lupin_home)["joints"]["elbow_flex"]
    assert (entry["zero"], entry["min"], entry["max"]) == (
        2048,
        math.ceil(900 + MARGIN),
        math.floor(3000 - MARGIN),
    )


async def test_a_subset_keeps_the_other_joints(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    sim = await make_sim(positions=START)
    tool = tools("calibrate", "--bus-port", sim.path, "--yes")
    await sweep(tool, sim, PATHS)
    assert await tool.wait() == 0, tool.output
    first = overlay(lupin_home)["joints"]
    redo = tools("calibrate", "--bus-port", sim.path, "--yes", "--joints", "gripper")
    await sweep(redo, sim, {6: ramp(2048, 1900, 2700)})
    assert await redo.wait() == 0, redo.output
    second = overlay(lupin_home)["joints"]
    assert {k: v for k, v in second.items() if k != "gripper"} == {
        k: v for k, v in first.items() if k != "gripper"
    }
    assert second["gripper"]["measurement"]["previous_homing_offset"] == expected_offset(1950, 2850)
    # The first backup was kept beside the new one, not overwritten.
    assert len(backups(lupin_home)) == 2


async def test_ctrl_c_during_the_eeprom_writes_names_the_restore_and_leaves_no_lock_open(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C lands while elbow_flex's offset write is on the wire (its reply never comes)."""
    sim = await make_sim(positions=START)
    respond = sim.bus.respond
    tool = tools("calibrate", "--bus-port", sim.path, "--yes")

    def interrupt_on_offset_write(packet, now):  # type: ignore[no-untyped-def]
        if packet.code == Instruction.WRITE and packet.id == 3 and packet.params[0] == 31:
            tool.interrupt()
            return []  # lost on the wire: the tool is still waiting when the Ctrl-C lands
        return respond(packet, now)

    monkeypatch.setattr(sim.bus, "respond", interrupt_on_offset_write)
    await sweep(tool, sim, PATHS)
    assert await tool.wait() == 130, tool.output
    out = tool.output
    assert "Interrupted during the EEPROM writes: some offsets may have changed" in out
    assert f"lupin offsets restore --bus-port {sim.path}" in out
    assert "Traceback" not in out
    assert not (lupin_home / "arm.yaml").exists()  # nothing saved from a half-done write
    assert sim.bus.servo(1).get("homing_offset") == -1944
    assert sim.bus.servo(3).get("homing_offset") == 0
    assert sim.bus.servo(3).get("lock") == 1  # relocked on the way out, reply or not

    monkeypatch.setattr(sim.bus, "respond", respond)
    restore = tools("offsets", "restore", "--bus-port", sim.path, "--yes")
    assert await restore.wait() == 0, restore.output
    assert all(sim.bus.servo(sid).get("homing_offset") == 0 for sid in NAMES)


async def test_interrupted_calibration_is_recovered_with_offsets_restore(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    sim = await make_sim(positions=START)
    respond = sim.bus.respond

    def die_on_offset_write(packet, now):  # type: ignore[no-untyped-def]
        # elbow_flex drops off the bus the moment its offset write arrives.
        if packet.code == Instruction.WRITE and packet.id == 3 and packet.params[0] == 31:
            sim.bus.kill(3)
        return respond(packet, now)

    monkeypatch.setattr(sim.bus, "respond", die_on_offset_write)
    tool = tools("calibrate", "--bus-port", sim.path, "--yes")
    await sweep(tool, sim, PATHS)
    assert await tool.wait() == 1, tool.output
    out = tool.output
    assert "Stopped: elbow_flex (id 3)" in out
    assert "Already changed: shoulder_pan (id 1), shoulder_lift (id 2)." in out
    assert f"lupin offsets restore --bus-port {sim.path}" in out
    assert not (lupin_home / "arm.yaml").exists()
    assert sim.bus.servo(1).get("homing_offset") == -1944
    assert sim.bus.servo(4).get("homing_offset") == 0  # it stopped at the failure

    sim.bus.revive(3)
    restore = tools("offsets", "restore", "--bus-port", sim.path, "--yes")
    assert await restore.wait() == 0, restore.output
    assert "shoulder_pan (id 1): homing offset -1944 -> 0" in restore.output
    for sid in NAMES:
        assert sim.bus.servo(sid).get("homing_offset") == 0
        assert sim.bus.servo(sid).get("lock") == 1
