"""Pad mapping files (packaged values, overrides, validation) and transport detection."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from lupin.config import ConfigError
from lupin.pad_mapping import (
    LAYOUTS,
    detect_layout,
    load_mapping,
    parse_input_devices,
    parse_mapping,
    resolve_layout,
)


def test_bluetooth_file_has_the_runbook_numbers() -> None:
    m = load_mapping("xbox-bluetooth")
    assert (m.source, m.require_enable_button, m.enable_button, m.enable_turbo_button) == (
        "joy",
        True,
        6,
        7,
    )
    assert (m.axis_linear.x, m.axis_linear.y, m.axis_angular.yaw) == (1, 0, 2)
    assert (m.scale_linear.x, m.scale_linear.y, m.scale_angular.yaw) == (0.2, 0.2, 0.7)
    assert (m.scale_linear_turbo.x, m.scale_linear_turbo.y) == (0.6, 0.6)
    assert m.scale_angular_turbo.yaw == 1.4
    assert (m.deadzone, m.autorepeat_rate, m.step_rad, m.update_rate_hz) == (0.15, 20.0, 0.15, 10.0)
    assert m.shoulder_disable_button == 6
    arm = m.arm_controls
    assert (arm["shoulder_pan"].plus_button, arm["shoulder_pan"].minus_button) == (1, 3)
    assert (arm["shoulder_lift"].plus_button, arm["shoulder_lift"].minus_button) == (4, 0)
    assert (arm["elbow"].axis, arm["wrist"].axis) == (7, 6)
    assert (m.gripper_open_axis, m.gripper_open_rest, m.gripper_open_full) == (4, 1.0, -1.0)
    assert (m.gripper_close_axis, m.gripper_open_enabled) == (5, True)


def test_usb_file_negates_scales_and_seeds_triggers_disabled() -> None:
    m = load_mapping("xbox-usb")
    assert (m.enable_button, m.enable_turbo_button, m.axis_angular.yaw, m.deadzone) == (
        4,
        5,
        3,
        0.1,
    )
    assert (m.scale_linear.x, m.scale_linear.y, m.scale_angular.yaw) == (-0.2, -0.2, -0.7)
    assert (m.scale_linear_turbo.x, m.scale_angular_turbo.yaw) == (-0.6, -1.4)
    assert (
        m.arm_controls["shoulder_pan"].minus_button,
        m.arm_controls["shoulder_lift"].plus_button,
    ) == (
        2,
        3,
    )
    assert not m.gripper_open_enabled and not m.gripper_close_enabled
    assert m.shoulder_disable_button == m.enable_button == 4


def test_ds4_has_no_deadman_and_feeds_manual() -> None:
    m = load_mapping("ds4")
    assert (m.require_enable_button, m.source) == (False, "manual")


def test_every_arm_role_has_a_control_of_its_own() -> None:
    for layout in LAYOUTS:
        assert set(load_mapping(layout).arm_controls) == {
            "shoulder_pan",
            "shoulder_lift",
            "elbow",
            "wrist",
            "wrist_roll",
        }


def test_lupin_home_overrides_the_packaged_file(lupin_home: Path) -> None:
    data = load_mapping("xbox-usb").model_dump(mode="json", exclude_none=True)
    data["deadzone"] = 0.2
    (lupin_home / "pads").mkdir()
    (lupin_home / "pads" / "xbox-usb.yaml").write_text(yaml.safe_dump(data))
    assert load_mapping("xbox-usb").deadzone == 0.2
    assert load_mapping("xbox-bluetooth").deadzone == 0.15


def _bad(change: dict[str, Any]) -> str:
    data = load_mapping("xbox-bluetooth").model_dump(mode="json", exclude_none=True)
    data.update(change)
    with pytest.raises(ConfigError) as info:
        parse_mapping(data, "pads/test.yaml")
    return str(info.value)


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        ({"enable_buton": 6}, "enable_buton: Extra inputs are not permitted"),
        ({"enable_button": -1}, "require_enable_button needs a dead-man button"),
        ({"deadzone": 0.95}, "deadzone: Input should be less than or equal to 0.9"),
        ({"autorepeat_rate": 0}, "autorepeat_rate"),
        ({"axis_angular": {"yaw": 1}}, "axis_angular.yaw: axis 1 is already used by axis_linear.x"),
        ({"enable_turbo_button": 6}, "button 6 is already used by enable_button"),
        ({"gripper_open_full": 0.95}, "gripper_open_enabled: needs an axis and |full - rest|"),
        ({"scale_linear": {"x": "fast"}}, "scale_linear.x"),
        ({"source": "auto"}, "source"),
    ],
)
def test_validation_errors_name_file_and_field(change: dict[str, Any], needle: str) -> None:
    message = _bad(change)
    assert message.startswith("pads/test.yaml: ")
    assert needle in message


def test_no_control_does_double_duty_across_lb_states() -> None:
    # The old right-stick-X: yaw with LB held, shoulder pan with LB released.
    message = _bad({"arm_controls": {"shoulder_pan": {"axis": 2, "sign": 1}}})
    assert "arm_controls.shoulder_pan: axis 2 is already used by axis_angular.yaw" in message
    message = _bad({"arm_controls": {"wrist_roll": {"plus_button": 7, "minus_button": 10}}})
    assert "button 7 is already used by enable_turbo_button" in message


def test_arm_control_is_buttons_xor_axis() -> None:
    assert "a button control needs two distinct" in _bad(
        {"arm_controls": {"wrist_roll": {"plus_button": 11, "minus_button": 11}}}
    )
    assert "an axis control takes axis >= 0 and no buttons" in _bad(
        {"arm_controls": {"elbow": {"axis": 7, "plus_button": 2}}}
    )


def test_a_broken_file_in_lupin_home_is_a_config_error(lupin_home: Path) -> None:
    (lupin_home / "pads").mkdir()
    path = lupin_home / "pads" / "ds4.yaml"
    path.write_text("source: manual\nrequire_enable_button: false\ndeadzone: [1]\n")
    with pytest.raises(ConfigError, match=rf"{path}: deadzone"):
        load_mapping("ds4")
    with pytest.raises(ConfigError, match="unknown pad layout 'xbox'"):
        load_mapping("xbox")


# -- /proc/bus/input/devices ----------------------------------------------------------------

KEYBOARD = """\
I: Bus=0019 Vendor=0000 Product=0001 Version=0000
N: Name="Power Button"
P: Phys=PNP0C0C/button/input0
S: Sysfs=/devices/LNXSYSTM:00/LNXSYBUS:00/PNP0C0C:00/input/input0
U: Uniq=
H: Handlers=kbd event0
B: PROP=0
B: EV=3
B: KEY=10000000000000 0

I: Bus=0011 Vendor=0001 Product=0001 Version=ab41
N: Name="AT Translated Set 2 keyboard"
P: Phys=isa0060/serio0/input0
S: Sysfs=/devices/platform/i8042/serio0/input/input3
U: Uniq=
H: Handlers=sysrq kbd leds event3
B: PROP=0
B: EV=120013
B: KEY=402000000 3803078f800d001 feffffdfffefffff fffffffffffffffe
B: MSC=10
B: LED=7

I: Bus=0003 Vendor=046d Product=c52b Version=0111
N: Name="Logitech USB Receiver Mouse"
P: Phys=usb-0000:00:14.0-1/input2:1
S: Sysfs=/devices/pci0000:00/0000:00:14.0/usb1/1-1/1-1:1.2/0003:046D:C52B.0003/input/input7
U: Uniq=
H: Handlers=mouse0 event5
B: PROP=0
B: EV=17
B: KEY=ffff0000 0 0 0 0
B: REL=1943
B: MSC=10
"""

XBOX_USB = """\
I: Bus=0003 Vendor=045e Product=02ea Version=0301
N: Name="Microsoft X-Box One S pad"
P: Phys=usb-0000:00:14.0-2/input0
S: Sysfs=/devices/pci0000:00/0000:00:14.0/usb1/1-2/1-2:1.0/input/input20
U: Uniq=
H: Handlers=event20 js0
B: PROP=0
B: EV=20000b
B: KEY=7cdb000000000000 0 0 0 0
B: ABS=3003f
B: FF=107030000 0
"""

XBOX_BT = """\
I: Bus=0005 Vendor=045e Product=0b13 Version=0509
N: Name="Xbox Wireless Controller"
P: Phys=dc:a6:32:12:34:56
S: Sysfs=/devices/virtual/misc/uhid/0005:045E:0B13.0004/input/input21
U: Uniq=44:16:22:aa:bb:cc
H: Handlers=event21 js1
B: PROP=0
B: EV=10001b
B: KEY=7fff000000000000 0 0 0 0
B: ABS=30627
B: MSC=10
"""

DS4 = """\
I: Bus=0003 Vendor=054c Product=09cc Version=8111
N: Name="Sony Interactive Entertainment Wireless Controller Touchpad"
P: Phys=usb-0000:00:14.0-3/input3
S: Sysfs=/devices/pci0000:00/0000:00:14.0/usb1/1-3/1-3:1.3/0003:054C:09CC.0005/input/input23
U: Uniq=
H: Handlers=mouse1 event23
B: PROP=5
B: EV=b
B: KEY=2420 0 10000 0 0 0 0 0 0 0 0
B: ABS=2608000 3

I: Bus=0003 Vendor=054c Product=09cc Version=8111
N: Name="Sony Interactive Entertainment Wireless Controller"
P: Phys=usb-0000:00:14.0-3/input3
S: Sysfs=/devices/pci0000:00/0000:00:14.0/usb1/1-3/1-3:1.3/0003:054C:09CC.0005/input/input22
U: Uniq=
H: Handlers=event22 js2
B: PROP=0
B: EV=20000b
B: KEY=7fdb000000000000 0 0 0 0
B: ABS=3003f
"""


def test_keyboards_and_mice_are_not_pads() -> None:
    assert parse_input_devices(KEYBOARD) == []
    assert detect_layout(KEYBOARD) == "xbox-usb"  # no pad: fall back to USB


@pytest.mark.parametrize(
    ("pad", "layout", "name", "node"),
    [
        (XBOX_USB, "xbox-usb", "Microsoft X-Box One S pad", "/dev/input/event20"),
        (XBOX_BT, "xbox-bluetooth", "Xbox Wireless Controller", "/dev/input/event21"),
        (DS4, "ds4", "Sony Interactive Entertainment Wireless Controller", "/dev/input/event22"),
    ],
)
def test_transport_detected_from_the_bus(pad: str, layout: str, name: str, node: str) -> None:
    text = KEYBOARD + "\n" + pad
    pads = parse_input_devices(text)
    assert [p.name for p in pads] == [name]
    assert pads[0].event_node == node
    assert detect_layout(text) == layout


def test_btn_south_alone_marks_a_pad_when_joydev_is_not_loaded() -> None:
    text = XBOX_BT.replace("Handlers=event21 js1", "Handlers=event21")
    assert detect_layout(text) == "xbox-bluetooth"


def test_forced_layout_wins_and_unreadable_file_falls_back(tmp_path: Path) -> None:
    devices = tmp_path / "devices"
    devices.write_text(XBOX_BT)
    assert resolve_layout(None, devices) == "xbox-bluetooth"
    assert resolve_layout("xbox-usb", devices) == "xbox-usb"
    assert resolve_layout(None, tmp_path / "missing") == "xbox-usb"
