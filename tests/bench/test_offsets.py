"""``lupin offsets`` end to end: show, backup, set, restore, and the LeRobot round trip."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import yaml
from benchkit import MakeSim, StartTool, backups, lerobot_degrees, lupin_degrees

from lupin.joints import RAD_PER_COUNT

MARGIN = 0.05 / RAD_PER_COUNT  # counts

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
    # What the restore overwrote is kept apart, so a restore from the wrong snapshot undoes.
    undo = lupin_home / "arm_offsets_before_restore.yaml"
    assert f"undo with: lupin offsets restore --bus-port {sim.path} --file {undo}" in (
        restore.output
    )
    assert yaml.safe_load(undo.read_text())["joints"] == {
        "elbow_flex": {"id": 3, "homing_offset": -1040}
    }
    undone = tools("offsets", "restore", "--file", str(undo), "--bus-port", sim.path, "--yes")
    assert await undone.wait() == 0, undone.output
    assert sim.bus.servo(3).get("homing_offset") == -1040


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


# A calibration as LeRobot's SO-101 follower writes it: drive_mode 0, the offset that put
# each joint's hand-held middle at 2047, the recorded stops in the present frame, and
# wrist_roll as a full-turn motor (the whole encoder).
LEROBOT = {
    "shoulder_pan": {"id": 1, "drive_mode": 0, "homing_offset": 1530,
                     "range_min": 850, "range_max": 3260},
    "shoulder_lift": {"id": 2, "drive_mode": 0, "homing_offset": -1007,
                      "range_min": 820, "range_max": 3280},
    "elbow_flex": {"id": 3, "drive_mode": 0, "homing_offset": 1053,
                   "range_min": 870, "range_max": 3100},
    "wrist_flex": {"id": 4, "drive_mode": 0, "homing_offset": 753,
                   "range_min": 880, "range_max": 3150},
    "wrist_roll": {"id": 5, "drive_mode": 0, "homing_offset": -847,
                   "range_min": 0, "range_max": 4095},
    "gripper": {"id": 6, "drive_mode": 0, "homing_offset": -47,
                "range_min": 2030, "range_max": 3450},
}  # fmt: skip


async def test_a_lerobot_calibration_reads_the_same_angles_here(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    """Imported, every physical pose reads here the angle LeRobot reads for it; exported
    again, the file is LeRobot's own."""
    sim = await make_sim()
    src = lupin_home / "so101_follower.json"
    src.write_text(json.dumps(LEROBOT, indent=4))
    imp = tools("offsets", "import-lerobot", str(src), "--bus-port", sim.path, "--yes")
    assert await imp.wait() == 0, imp.output
    assert "shoulder_pan (id 1): homing offset 0 -> 1530" in imp.output
    assert "wrist_roll: LeRobot's range is the whole turn" in imp.output
    for motor in LEROBOT.values():
        assert sim.bus.servo(motor["id"]).get("homing_offset") == motor["homing_offset"]

    # The soft limits sit the margin inside LeRobot's recorded stops, as after calibrate.
    saved = yaml.safe_load((lupin_home / "arm.yaml").read_text())["joints"]
    for name, motor in LEROBOT.items():
        lo, hi = motor["range_min"], motor["range_max"]
        assert saved[name]["min"] == math.ceil(lo + MARGIN), name
        assert saved[name]["max"] == min(math.floor(hi - MARGIN), 4095), name
        m = saved[name]["measurement"]
        assert (m["swept_min"], m["swept_max"], m["margin_rad"]) == (lo, hi, 0.05)

    # The same physical poses, read by both: within a count (LeRobot divides by 4095).
    for name, motor in LEROBOT.items():
        servo = sim.bus.servo(motor["id"])
        lo, hi = motor["range_min"], motor["range_max"]
        for present in (lo + 40, (lo + hi) // 2, (3 * lo + hi) // 4, hi - 40):
            servo.move_by_hand(present)
            p = servo.present_position
            ours, theirs = lupin_degrees(lupin_home, name, p), lerobot_degrees(p, motor)
            assert ours == pytest.approx(theirs, abs=0.1), (name, p, ours, theirs)

    # Exported again: the stops, not the soft limits, so LeRobot's scale is unchanged.
    out = lupin_home / "again.json"
    export = tools("offsets", "export-lerobot", str(out), "--bus-port", sim.path)
    assert await export.wait() == 0, export.output
    assert json.loads(out.read_text()) == LEROBOT
    assert "No sweep on record" not in export.output


async def test_a_calibration_without_a_sweep_exports_its_soft_limits(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    """An arm.yaml written by hand records no stops: its limits go out (inside the stops),
    and it says so; the offsets go out as the servos hold them."""
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
    assert "No sweep on record for the offsets shoulder_pan, shoulder_lift" in export.output
    exported = json.loads(out.read_text())
    assert list(exported) == NAMES
    assert exported["shoulder_pan"] == {
        "id": 1,
        "drive_mode": 0,
        "homing_offset": -1944,
        "range_min": 1400,
        "range_max": 2700,
    }

    # On a fresh arm, importing that file puts the same offsets back, verified, after a backup.
    for sid in OFFSETS:
        sim.bus.servo(sid).set("homing_offset", 0)
    (lupin_home / "arm.yaml").unlink()
    imp = tools("offsets", "import-lerobot", str(out), "--bus-port", sim.path, "--yes")
    assert await imp.wait() == 0, imp.output
    assert "shoulder_pan (id 1): homing offset 0 -> -1944" in imp.output
    for sid, offset in OFFSETS.items():
        assert sim.bus.servo(sid).get("homing_offset") == offset
    saved = yaml.safe_load((lupin_home / "arm.yaml").read_text())["joints"]
    assert saved["shoulder_pan"]["zero"] == 2050  # the middle of LeRobot's range
    assert (lupin_home / "arm_offsets_backup.yaml").exists()


async def test_lerobot_import_refuses_a_range_too_short_for_the_margin(
    make_sim: MakeSim, tools: StartTool, lupin_home: Path
) -> None:
    sim = await make_sim()
    path = lupin_home / "short.json"
    motor = {**LEROBOT["elbow_flex"], "range_min": 2000, "range_max": 2060}
    path.write_text(json.dumps({"elbow_flex": motor}))
    tool = tools("offsets", "import-lerobot", str(path), "--bus-port", sim.path, "--yes")
    assert await tool.wait() == 1
    assert "elbow_flex: swept only 0.092 rad, too short for the 0.05 rad margin" in tool.output
    assert "Nothing was written" in tool.output
    assert not sim.bus.writes()


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
