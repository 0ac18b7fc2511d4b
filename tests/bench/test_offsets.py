"""``lupin offsets`` end to end: show, backup, set, restore, and the LeRobot round trip."""

from __future__ import annotations

import json
from pathlib import Path

import yaml
from benchkit import MakeSim, StartTool, backups

OFFSETS = {1: -1944, 2: 2, 3: -98, 4: 2, 5: 52, 6: 352}
NAMES = ["shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper"]


async def test_show_backup_set_restore(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    sim = await make_sim()
    sim.bus.servo(2).set("homing_offset", 17)

    show = tools("offsets", "show", "--bus-port", sim.path)
    assert await show.wait() == 0
    assert "shoulder_lift    2      17" in show.output

    backup = tools("offsets", "backup", "--bus-port", sim.path)
    assert await backup.wait() == 0
    saved = yaml.safe_load((lupin_home / "arm_offsets_backup.yaml").read_text())
    assert saved["joints"]["shoulder_lift"] == {"id": 2, "homing_offset": 17}
    assert set(saved["joints"]) == set(NAMES)
    assert not sim.bus.writes()  # show and backup are read-only

    # set takes register values and folds modulo 4096 (3056 is -1040), after a backup.
    setter = tools("offsets", "set", "elbow_flex=3056", "--bus-port", sim.path)
    await setter.expect("elbow_flex: 3056 folded modulo 4096 into ±2047: -1040")
    await setter.expect("elbow_flex (id 3): homing offset 0 -> -1040")
    await setter.expect("Write these offsets? [y/N]")
    setter.send("y\n")
    assert await setter.wait() == 0, setter.output
    assert sim.bus.servo(3).get("homing_offset") == -1040
    assert len(backups(lupin_home)) == 2  # the older one kept beside it

    restore = tools("offsets", "restore", "--bus-port", sim.path, "--yes")
    assert await restore.wait() == 0, restore.output
    assert "elbow_flex (id 3): homing offset -1040 -> 0" in restore.output
    assert sim.bus.servo(3).get("homing_offset") == 0
    assert sim.bus.servo(2).get("homing_offset") == 17  # untouched: not in that backup


async def test_restore_refuses_a_backup_for_other_servos(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    sim = await make_sim()
    bad = {"joints": {"elbow_flex": {"id": 9, "homing_offset": 5}}}
    (lupin_home / "arm_offsets_backup.yaml").write_text(yaml.safe_dump(bad))
    tool = tools("offsets", "restore", "--bus-port", sim.path, "--yes")
    assert await tool.wait() == 2
    assert "joints.elbow_flex.id: 9 but the profile says 3" in tool.output
    assert not sim.bus.writes()


async def test_restore_asks_before_releasing_torque(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    sim = await make_sim()
    sim.bus.servo(1).set("homing_offset", 40)
    backup = {"joints": {"shoulder_pan": {"id": 1, "homing_offset": 0}}}
    (lupin_home / "arm_offsets_backup.yaml").write_text(yaml.safe_dump(backup))
    sim.bus.servo(1).set("torque_enable", 1)
    tool = tools("offsets", "restore", "--bus-port", sim.path)
    await tool.expect("Write these offsets? [y/N]")
    tool.send("y\n")
    await tool.expect("Release torque now? [y/N]")
    tool.send("n\n")
    assert await tool.wait() == 1
    assert sim.bus.servo(1).torque and sim.bus.servo(1).get("homing_offset") == 40


async def test_lerobot_export_import_round_trip(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    sim = await make_sim()
    for sid, offset in OFFSETS.items():
        sim.bus.servo(sid).set("homing_offset", offset)
    joints = {
        name: {"zero": 2048, "min": 1400 + 10 * i, "max": 2700 - 10 * i}
        for i, name in enumerate(NAMES)
    }
    (lupin_home / "arm.yaml").write_text(yaml.safe_dump({"joints": joints}))

    out = lupin_home / "follower.json"
    export = tools("offsets", "export-lerobot", str(out), "--bus-port", sim.path)
    assert await export.wait() == 0, export.output
    exported = json.loads(out.read_text())
    assert exported["shoulder_pan"] == {
        "id": 1,
        "drive_mode": 0,
        "homing_offset": -1944,
        "range_min": 1400,
        "range_max": 2700,
    }
    assert list(exported) == NAMES

    # A fresh arm: offsets gone, no calibration file.
    for sid in OFFSETS:
        sim.bus.servo(sid).set("homing_offset", 0)
    (lupin_home / "arm.yaml").unlink()
    imp = tools("offsets", "import-lerobot", str(out), "--bus-port", sim.path, "--yes")
    assert await imp.wait() == 0, imp.output
    assert "shoulder_pan (id 1): homing offset 0 -> -1944" in imp.output
    for sid, offset in OFFSETS.items():
        assert sim.bus.servo(sid).get("homing_offset") == offset
    saved = yaml.safe_load((lupin_home / "arm.yaml").read_text())["joints"]
    for name, entry in joints.items():
        assert (saved[name]["min"], saved[name]["max"]) == (entry["min"], entry["max"])
        assert saved[name]["zero"] == 2050  # the middle of LeRobot's range
    assert (lupin_home / "arm_offsets_backup.yaml").exists()

    again = lupin_home / "again.json"
    export2 = tools("offsets", "export-lerobot", str(again), "--bus-port", sim.path)
    assert await export2.wait() == 0
    assert json.loads(again.read_text()) == exported


async def test_lerobot_import_refuses_a_mismatched_file(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    sim = await make_sim()
    path = lupin_home / "other.json"
    motor = {"id": 4, "drive_mode": 0, "homing_offset": 10, "range_min": 100, "range_max": 4000}
    path.write_text(json.dumps({"elbow_flex": motor}))
    tool = tools("offsets", "import-lerobot", str(path), "--bus-port", sim.path, "--yes")
    assert await tool.wait() == 2
    assert "elbow_flex.id: 4, but elbow_flex is id 3 here" in tool.output
    assert not sim.bus.writes()
