"""Pad mapping files (teleop_twist_joy's parameter names plus arm and trigger keys),
and transport detection from ``/proc/bus/input/devices``.

The index order a pad presents is decided by the kernel driver, and the driver
by the transport: over a USB cable the Xbox pad binds xpad, over Bluetooth the
shifted HID layout (LB at button 6, not 4). So there is one mapping file per
transport (runbook, "Xbox control layout"), picked by detection or forced by
``--pad-layout``. The packaged files live in ``config/pads/``; the calibrator
writes ``$LUPIN_HOME/pads/<layout>.yaml``, which wins when present.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, ValidationError, model_validator

from lupin.config import ConfigError, format_validation_error, lupin_home, read_yaml
from lupin.config_models import Strict

LAYOUTS = ("xbox-usb", "xbox-bluetooth", "ds4")
# With no pad detected the runbook falls back to USB (the cable is the recovery path).
FALLBACK_LAYOUT = "xbox-usb"
DEVICES_PATH = Path("/proc/bus/input/devices")

Index = Annotated[int, Field(ge=-1, le=63)]  # -1 = unused, as in teleop_twist_joy
Unit = Annotated[float, Field(ge=-1.0, le=1.0)]
Scale = Annotated[float, Field(ge=-10.0, le=10.0)]
ArmRole = Literal["shoulder_pan", "shoulder_lift", "elbow", "wrist", "wrist_roll"]
AXIS_KEYS = ("axis", "rest", "full")
ARM_ROLES: tuple[ArmRole, ...] = ("shoulder_pan", "shoulder_lift", "elbow", "wrist", "wrist_roll")


class LinearAxes(Strict):
    x: Index = -1
    y: Index = -1


class LinearScales(Strict):
    x: Scale = 0.0
    y: Scale = 0.0


class AngularAxes(Strict):
    yaw: Index = -1


class AngularScales(Strict):
    yaw: Scale = 0.0


class ArmControl(Strict):
    """One arm role: a +/- button pair, or an axis (the D-pad) whose sign says which way is +."""

    plus_button: Index | None = None
    minus_button: Index | None = None
    axis: Index | None = None
    sign: Literal[-1, 1] = 1

    @model_validator(mode="after")
    def _one_kind(self) -> ArmControl:
        plus, minus = self.plus_button, self.minus_button
        if self.axis is not None:
            if self.axis < 0 or plus is not None or minus is not None:
                raise ValueError("an axis control takes axis >= 0 and no buttons")
        elif plus is None or minus is None or min(plus, minus) < 0 or plus == minus:
            raise ValueError("a button control needs two distinct plus_button/minus_button >= 0")
        return self

    def buttons(self) -> tuple[int, ...]:
        return tuple(b for b in (self.plus_button, self.minus_button) if b is not None)


class PadMapping(Strict):
    description: str = ""
    # Which mux source the base twist feeds: the dead-man Xbox path is `joy` (priority
    # 100); the DS4 has no dead-man and must stay on `manual` (runbook, "Why the dead-man").
    source: Literal["joy", "manual"]
    require_enable_button: bool = True
    enable_button: Index = -1
    enable_turbo_button: Index = -1
    axis_linear: LinearAxes = LinearAxes()
    scale_linear: LinearScales = LinearScales()
    scale_linear_turbo: LinearScales = LinearScales()
    axis_angular: AngularAxes = AngularAxes()
    scale_angular: AngularScales = AngularScales()
    scale_angular_turbo: AngularScales = AngularScales()
    deadzone: Annotated[float, Field(ge=0.0, le=0.9)] = 0.05
    autorepeat_rate: Annotated[float, Field(gt=0.0, le=100.0)] = 20.0
    # arm_teleop
    step_rad: Annotated[float, Field(gt=0.0, le=1.0)] = 0.15
    update_rate_hz: Annotated[float, Field(gt=0.0, le=50.0)] = 10.0
    shoulder_disable_button: Index = -1
    arm_controls: dict[ArmRole, ArmControl] = Field(default_factory=dict)
    # gripper triggers: pull = clamp((v - rest) / (full - rest), 0, 1)
    gripper_open_axis: Index = -1
    gripper_open_rest: Unit = 1.0
    gripper_open_full: Unit = -1.0
    gripper_open_enabled: bool = False
    gripper_close_axis: Index = -1
    gripper_close_rest: Unit = 1.0
    gripper_close_full: Unit = -1.0
    gripper_close_enabled: bool = False

    @model_validator(mode="after")
    def _rules(self) -> PadMapping:
        if self.require_enable_button and self.enable_button < 0:
            raise ValueError("enable_button: require_enable_button needs a dead-man button")
        if self.source == "joy" and not self.require_enable_button:
            # Only a dead-man gated path may hold priority 100: it must be able to fall silent.
            raise ValueError("source: a pad without a dead-man must feed 'manual', not 'joy'")
        for side in ("open", "close"):
            axis, rest, full = (getattr(self, f"gripper_{side}_{k}") for k in AXIS_KEYS)
            if getattr(self, f"gripper_{side}_enabled") and (axis < 0 or abs(full - rest) < 0.2):
                raise ValueError(f"gripper_{side}_enabled: needs an axis and |full - rest| >= 0.2")
        _check_no_double_duty(self)
        return self


def _check_no_double_duty(m: PadMapping) -> None:
    """No control may do two jobs: a brushed input must never move two things.

    The runbook's right stick used to drive yaw with LB held and pan the shoulder
    with LB released, and an LB release flicked the arm; so every index has one
    role in every LB state. shoulder_disable_button is meant to be the dead-man.
    """
    buttons: dict[int, str] = {}
    axes: dict[int, str] = {}

    def claim(table: dict[int, str], index: int | None, role: str, kind: str) -> None:
        if index is None or index < 0:
            return
        if index in table:
            raise ValueError(f"{role}: {kind} {index} is already used by {table[index]}")
        table[index] = role

    claim(buttons, m.enable_button if m.require_enable_button else -1, "enable_button", "button")
    claim(buttons, m.enable_turbo_button, "enable_turbo_button", "button")
    if m.shoulder_disable_button not in (-1, m.enable_button):
        claim(buttons, m.shoulder_disable_button, "shoulder_disable_button", "button")
    claim(axes, m.axis_linear.x, "axis_linear.x", "axis")
    claim(axes, m.axis_linear.y, "axis_linear.y", "axis")
    claim(axes, m.axis_angular.yaw, "axis_angular.yaw", "axis")
    claim(axes, m.gripper_open_axis, "gripper_open_axis", "axis")
    claim(axes, m.gripper_close_axis, "gripper_close_axis", "axis")
    for role, control in m.arm_controls.items():
        for b in control.buttons():
            claim(buttons, b, f"arm_controls.{role}", "button")
        claim(axes, control.axis, f"arm_controls.{role}", "axis")


# -- loading -------------------------------------------------------------------------


def override_path(layout: str, home: Path | None = None) -> Path:
    """Where the calibrator writes, and where a site mapping overrides the packaged one."""
    return (home or lupin_home()) / "pads" / f"{layout}.yaml"


def parse_mapping(data: Mapping[str, Any], source: str) -> PadMapping:
    try:
        return PadMapping.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(source, exc, data)) from None


def load_mapping(layout: str, *, home: Path | None = None) -> PadMapping:
    """The mapping for ``layout``: ``$LUPIN_HOME/pads/<layout>.yaml``, else the packaged file."""
    if layout not in LAYOUTS:
        raise ConfigError(f"unknown pad layout {layout!r} (known: {', '.join(LAYOUTS)})")
    path = override_path(layout, home)
    if path.exists():
        return parse_mapping(read_yaml(path), str(path))
    res = resources.files("lupin_config") / "pads" / f"{layout}.yaml"
    source = f"config/pads/{layout}.yaml"
    return parse_mapping(read_yaml(source, res.read_text(encoding="utf-8")), source)


# -- transport detection -----------------------------------------------------------

BUS_USB, BUS_BLUETOOTH = 0x0003, 0x0005
VENDOR_SONY = 0x054C
BTN_SOUTH = 0x130  # BTN_A / BTN_GAMEPAD: the bit that makes an input device a gamepad


@dataclass(frozen=True, slots=True)
class InputDeviceInfo:
    name: str
    bus: int
    vendor: int
    product: int
    handlers: tuple[str, ...]

    @property
    def is_gamepad(self) -> bool:
        return any(h.startswith("js") for h in self.handlers)

    @property
    def layout(self) -> str:
        if self.vendor == VENDOR_SONY:
            return "ds4"
        return "xbox-bluetooth" if self.bus == BUS_BLUETOOTH else "xbox-usb"

    @property
    def event_node(self) -> str | None:
        node = next((h for h in self.handlers if h.startswith("event")), None)
        return f"/dev/input/{node}" if node else None


def _has_key_bit(bitmap: str, bit: int) -> bool:
    words = bitmap.split()  # most significant word first, 64 bits each on 64-bit kernels
    word = len(words) - 1 - bit // 64
    return 0 <= word < len(words) and bool(int(words[word], 16) >> (bit % 64) & 1)


_IDENT = re.compile(
    r"^I:.*Bus=([0-9a-fA-F]+)\s+Vendor=([0-9a-fA-F]+)\s+Product=([0-9a-fA-F]+)", re.M
)


def parse_input_devices(text: str) -> list[InputDeviceInfo]:
    """Parse ``/proc/bus/input/devices``; keeps only gamepads (a ``js`` handler or BTN_SOUTH)."""
    pads = []
    for block in re.split(r"\n\s*\n", text.strip()):
        ident = _IDENT.search(block)
        if ident is None:
            continue
        name = re.search(r'^N: Name="(.*)"', block, re.M)
        handlers = re.search(r"^H: Handlers=(.*)$", block, re.M)
        keys = re.search(r"^B: KEY=(.*)$", block, re.M)
        info = InputDeviceInfo(
            name=name.group(1) if name else "",
            bus=int(ident.group(1), 16),
            vendor=int(ident.group(2), 16),
            product=int(ident.group(3), 16),
            handlers=tuple(handlers.group(1).split()) if handlers else (),
        )
        if info.is_gamepad or (keys is not None and _has_key_bit(keys.group(1), BTN_SOUTH)):
            pads.append(info)
    return pads


def detect_layout(devices_text: str) -> str:
    """The layout of the first pad found (Bus=0003 USB, 0005 Bluetooth, Sony = ds4), else USB."""
    pads = parse_input_devices(devices_text)
    return pads[0].layout if pads else FALLBACK_LAYOUT


def resolve_layout(forced: str | None, devices_path: Path = DEVICES_PATH) -> str:
    """``--pad-layout`` when given, else detection; an unreadable file means no pad found."""
    if forced is not None:
        return forced
    try:
        text = devices_path.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return FALLBACK_LAYOUT
    return detect_layout(text)
