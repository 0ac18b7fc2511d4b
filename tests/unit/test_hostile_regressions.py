"""Bugs the reliability suite's hostile-input tests found, pinned at the unit level.

Each test names the input that used to crash, hang or mislead, and what it gets now.
The end-to-end versions live in tests/reliability/test_hostile_*.py.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import pytest
from pydantic import ValidationError

from lupin import api_models as m
from lupin import control_table as ct
from lupin.api.openapi import build_document
from lupin.arm import ArmCommander
from lupin.bus import BusStats, SyncReadResult
from lupin.config import ConfigError, load_profile, read_yaml
from lupin.control_loop import ControlLoop
from lupin.joints import arm_geometry
from lupin.pad import PadFrame
from lupin.pad_mapping import load_mapping
from lupin.pad_task import PadStatus, _PadLoop
from lupin.teleop import BaseTeleop


def test_pose_go_speed_has_a_floor_so_the_stream_stays_bounded() -> None:
    # 1e-12 rad/s was accepted and asked stream_points for ~1e13 setpoints: a frozen loop.
    with pytest.raises(ValidationError, match="speed_rad_s"):
        m.PoseGoRequest(speed_rad_s=1e-12)
    assert m.PoseGoRequest(speed_rad_s=m.MIN_POSE_SPEED_RAD_S).speed_rad_s == 0.01


def test_a_pose_cannot_be_taught_empty() -> None:
    # {"joints_rad": {}} was stored; going to it named no joint and answered 500.
    with pytest.raises(ValidationError, match="joints_rad"):
        m.PoseSaveRequest(joints_rad={})
    assert m.PoseSaveRequest().joints_rad is None  # capture the measured pose
    assert m.PoseSaveRequest(joints_rad={"elbow_flex": 0.1}).joints_rad == {"elbow_flex": 0.1}


def test_the_document_links_a_taught_pose_to_what_takes_its_name() -> None:
    doc = build_document(None, token_required=False)
    links = doc["paths"]["/api/arm/poses/{pose}"]["put"]["responses"]["200"]["links"]
    assert {link["operationId"] for link in links.values()} == {
        "get_pose",
        "go_pose",
        "delete_pose",
    }
    assert all(link["parameters"] == {"pose": "$response.body#/name"} for link in links.values())
    ops = {op["operationId"] for path in doc["paths"].values() for op in path.values()}
    assert {link["operationId"] for link in links.values()} <= ops


# -- configuration files ----------------------------------------------------------------------


@pytest.fixture()
def home(tmp_path: Path) -> Path:
    h = tmp_path / "home"
    h.mkdir()
    return h


def refused(path: Path | str, *, home: Path, config: Path | None = None) -> str:
    with pytest.raises(ConfigError) as info:
        if config is None:
            load_profile(str(path), home=home)
        else:
            load_profile(config_file=config, home=home)
    return str(info.value)


def test_deep_nesting_is_a_config_error_not_a_recursion_error(tmp_path: Path) -> None:
    path = tmp_path / "deep.yaml"
    path.write_text("a: " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(ConfigError, match=r"deep\.yaml: not valid YAML: nested too deeply"):
        read_yaml(path)


def test_a_number_past_the_int_digit_limit_is_a_config_error(tmp_path: Path) -> None:
    path = tmp_path / "big.yaml"
    path.write_text("control: {tick_hz: 1" + "0" * 5000 + "}\n")
    with pytest.raises(ConfigError, match=r"big\.yaml: not valid YAML: .*4300 digits"):
        read_yaml(path)


def test_a_key_given_twice_is_refused_with_its_name_and_line(tmp_path: Path) -> None:
    path = tmp_path / "twice.yaml"
    path.write_text("arm:\n  envelope_deg: 90\n  envelope_deg: 120\n")
    with pytest.raises(ConfigError, match=r"(?s)twice\.yaml.*duplicate key 'envelope_deg'.*line 3"):
        read_yaml(path)


def test_merge_keys_may_still_be_overridden(tmp_path: Path) -> None:
    path = tmp_path / "merge.yaml"
    path.write_text("base: &b {p: 1, d: 2}\ngains:\n  <<: *b\n  p: 5\n")
    assert read_yaml(path)["gains"] == {"p": 5, "d": 2}


def test_profile_path_that_cannot_be_read_is_a_config_error(tmp_path: Path, home: Path) -> None:
    folder = tmp_path / "robot.yaml"
    folder.mkdir()
    assert "robot.yaml: cannot read" in refused(folder, home=home)
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"\x00\xff\xfe garbage")
    assert "binary.yaml: cannot read" in refused(binary, home=home)
    empty = tmp_path / "empty.yaml"
    empty.write_text("")
    message = refused(empty, home=home)  # was "no such file"
    assert "empty.yaml" in message and "no such file" not in message and "name" in message
    assert "no such file" in refused(tmp_path / "missing.yaml", home=home)


@pytest.mark.parametrize("site", ["arm: 5\n", "arm: {joints: 5}\n", "arm: {joints: abc}\n"])
def test_a_malformed_arm_with_an_overlay_is_named_not_a_crash(
    tmp_path: Path, home: Path, site: str
) -> None:
    (home / "arm.yaml").write_text("joints: {elbow_flex: {zero: 2048, min: 1024, max: 3072}}\n")
    config = tmp_path / "site.yaml"
    config.write_text(site)
    message = refused("so101", home=home, config=config)
    assert "site.yaml" in message and "arm" in message
    assert "not a joint of this profile" not in message  # the overlay is not to blame


# -- a garbled but well-formed reading --------------------------------------------------------


class ScriptedBus:
    """The ServoBus calls the control tick makes, answered from ``positions``."""

    def __init__(self, positions: dict[int, int]) -> None:
        self.positions = positions
        self.stats = BusStats()
        self.goals: list[tuple[int, int]] = []  # (servo id, goal position) as written

    async def sync_read(self, ids: Sequence[int], address: int, length: int, **_: Any) -> Any:
        result = SyncReadResult()
        for sid in ids:
            pos = ct.encode_value(ct.REGISTERS["present_position"], self.positions[sid])
            result.data[sid] = pos + bytes(length - 2)
        return result

    async def sync_write(
        self, address: int, length: int, data: Mapping[int, bytes], **_: Any
    ) -> None:
        if address == ct.REGISTERS["goal_position"].address:
            for sid, raw in data.items():
                self.goals.append((sid, ct.decode_value(ct.REGISTERS["goal_position"], raw[:2])))

    async def write(self, sid: int, address: int, data: bytes, **_: Any) -> bool:
        if address == ct.REGISTERS["goal_position"].address:
            self.goals.append((sid, ct.decode_value(ct.REGISTERS["goal_position"], data)))
        return True

    async def read(self, *_: Any, **__: Any) -> None:
        return None


async def holding_loop(home: Path) -> tuple[ControlLoop, ScriptedBus, list[float]]:
    """A control loop on a scripted bus, the arm energised and holding at 2048."""
    geometry = arm_geometry(load_profile(home=home).arm)
    bus = ScriptedBus({g.id: 2048 for g in geometry.values()})
    now = [0.0]
    arm = ArmCommander(geometry, resync_threshold=0.08)
    loop = ControlLoop(
        bus,  # type: ignore[arg-type]
        arm,
        geometry,
        None,
        lambda t: (None, 0.0),
        clock=lambda: now[0],
    )
    for _ in range(2):
        now[0] += 0.01
        await loop.tick()
    loop.request_enable()
    while not arm.gate_open:
        now[0] += 0.01
        await loop.tick()
    bus.goals.clear()
    return loop, bus, now


async def test_one_garbled_reading_is_held_not_adopted_and_sent_as_a_goal(home: Path) -> None:
    # A cut reply completed by the next servo's bytes passes the one-byte checksum 1 in 256
    # times: the elbow "read" 3900 for one tick. Resync adopted it and wrote it as a goal.
    loop, bus, now = await holding_loop(home)
    for position in (3900, 2048, 2048, 100, 2048):
        bus.positions[3] = position
        now[0] += 0.01
        await loop.tick()
    assert bus.goals == []  # the arm held still
    assert loop.arm.resyncs == 0
    assert loop.readings[3].position == 2048 and loop.readings[3].misses == 0
    assert bus.stats.failures["implausible"] == 2


async def test_a_real_jump_is_accepted_once_a_second_reading_confirms_it(home: Path) -> None:
    loop, bus, now = await holding_loop(home)
    bus.positions[3] = 2600  # moved by something else (the resync case), and stays there
    now[0] += 0.01
    await loop.tick()
    assert loop.readings[3].position == 2048 and loop.readings[3].misses == 1
    now[0] += 0.01
    await loop.tick()
    assert loop.readings[3].position == 2600 and loop.readings[3].misses == 0
    assert loop.arm.resyncs == 1  # re-adopted, one tick later than without the check
    # Motion within what a servo can do in a tick is never held.
    for step in range(1, 6):
        bus.positions[3] = 2600 + 40 * step
        now[0] += 0.01
        await loop.tick()
        assert loop.readings[3].position == 2600 + 40 * step
    assert bus.stats.failures["implausible"] == 1


# -- pad axes that are not numbers ------------------------------------------------------------


def test_bad_pad_axes_are_warned_about_by_index_and_value_at_most_every_period(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # NaN, infinite or far out-of-range axes read as neutral (nothing moves), but a pad
    # that sent them did so without a word in the log.
    caplog.set_level(logging.WARNING, logger="lupin.pad_task")
    twists: list[object] = []
    loop = _PadLoop(
        BaseTeleop(load_mapping("xbox-bluetooth")),
        None,
        lambda source, twist: twists.append(twist),
        None,
        lambda: 0.0,
        PadStatus(reader="replay:bad.jsonl"),
        None,
    )
    loop.handle(PadFrame(0.0, (math.nan, 0.0, 5.0), ()), 0.0)
    loop.handle(PadFrame(0.1, (math.inf,), ()), 0.1)  # within the period: counted only
    loop.handle(PadFrame(0.2, (1.0, -1.0, 1.0005), ()), 0.2)  # in range (float noise)
    loop.handle(PadFrame(6.0, (0.0, -1e9), ()), 6.0)
    warnings = [r.getMessage() for r in caplog.records]
    assert len(warnings) == 2, warnings
    assert "replay:bad.jsonl" in warnings[0] and "0=nan, 2=5.0" in warnings[0]
    assert "neutral" in warnings[0] and "(1 such frames)" in warnings[0]
    assert "1=-1000000000.0" in warnings[1] and "(3 such frames)" in warnings[1]
    assert loop.bad_frames == 3 and twists == []
