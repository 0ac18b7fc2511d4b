"""The robot profile as pydantic models: what a YAML profile may say, and what it may not.

Every model forbids unknown keys: a typo in a profile (``invret: true``) must be an
error at load, not a joint that silently moves the wrong way. Cross-field rules
(ids, names, zero inside its limits) live in :class:`RobotProfile` so they are
checked once, after the ``$LUPIN_HOME/arm.yaml`` overlay has been applied.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

Counts = Annotated[int, Field(ge=0, le=4095)]
ServoId = Annotated[int, Field(ge=0, le=253)]
PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
Name = Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]*$", max_length=40)]


class Strict(BaseModel):
    """Base for every config model: unknown keys and NaN are refused."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)


class BusConfig(Strict):
    port: str = "/dev/lupin_servos"
    baud: Literal[38400, 57600, 115200, 128000, 250000, 500000, 1000000] = 1_000_000
    # Extra time on top of the computed wire time before a reply counts as missing.
    reply_margin_s: Annotated[float, Field(gt=0, le=0.5)] = 0.006
    retries: Annotated[int, Field(ge=0, le=5)] = 1


class Gains(Strict):
    p: Annotated[int, Field(ge=0, le=254)] = 32
    d: Annotated[int, Field(ge=0, le=254)] = 32
    i: Annotated[int, Field(ge=0, le=254)] = 0


class JointConfig(Strict):
    """One arm joint. zero/min/max are encoder counts; the overlay replaces them."""

    name: Name
    id: ServoId
    invert: bool = False
    zero: Counts = 2048
    min: Counts = 1024
    max: Counts = 3072
    # The software envelope (URDF-like) intersected with the servo limit; None = arm default.
    envelope_deg: Annotated[float, Field(gt=0, le=180)] | None = None
    gains: Gains = Gains()


class GripperConfig(Strict):
    """How the HMI's gripper slider maps onto the gripper joint.

    On the runbook's jaw the HMI's -30 deg is OPEN and +30 deg CLOSED; the
    mapping is data so a jaw with the opposite sense needs no code change.
    """

    joint: Name
    hmi_open_deg: float = -30.0
    hmi_closed_deg: float = 30.0
    open_rad: float
    closed_rad: float

    @model_validator(mode="after")
    def _distinct(self) -> GripperConfig:
        if self.hmi_open_deg == self.hmi_closed_deg:
            raise ValueError("hmi_open_deg and hmi_closed_deg must differ")
        if self.open_rad == self.closed_rad:
            raise ValueError("open_rad and closed_rad must differ")
        return self


class ArmConfig(Strict):
    envelope_deg: Annotated[float, Field(gt=0, le=180)] = 90.0
    joints: Annotated[list[JointConfig], Field(min_length=1)]
    gripper: GripperConfig | None = None
    # Tolerance for "settled" (above the droop of a gravity-loaded joint: the seed measured
    # 0.031 rad at Kp 32) and the resync threshold (runbook 0.08 rad).
    goal_tolerance_rad: Annotated[float, Field(gt=0, le=0.5)] = 0.05
    resync_threshold_rad: Annotated[float, Field(gt=0, le=1.0)] = 0.08
    preset_travel_s: PositiveFloat = 3.0
    init_travel_s: PositiveFloat = 3.0
    default_speed_deg_s: PositiveFloat = 30.0


class WheelConfig(Strict):
    name: Name
    id: ServoId
    invert: bool = False


class BaseConfig(Strict):
    kind: Literal["differential", "mecanum"]
    wheels: Annotated[list[WheelConfig], Field(min_length=2, max_length=4)]
    wheel_radius_m: PositiveFloat
    track_width_m: PositiveFloat
    wheelbase_m: PositiveFloat | None = None
    max_wheel_speed_rad_s: PositiveFloat = 4.0
    # The base's own timeout: with no command for this long the wheels stop,
    # whatever the mux does (the mux outputs nothing when no source is active).
    command_timeout_s: Annotated[float, Field(gt=0, le=5)] = 0.5

    @model_validator(mode="after")
    def _wheel_count(self) -> BaseConfig:
        want = 2 if self.kind == "differential" else 4
        if len(self.wheels) != want:
            raise ValueError(f"a {self.kind} base needs {want} wheels, got {len(self.wheels)}")
        if self.kind == "mecanum" and self.wheelbase_m is None:
            raise ValueError("a mecanum base needs wheelbase_m")
        return self


class MuxTopic(Strict):
    """One twist_mux input: a source (or lock) with a priority and a timeout (0 = never expires)."""

    topic: str
    timeout: Annotated[float, Field(ge=0, le=60)]
    priority: Annotated[int, Field(ge=0, le=255)]
    sim_only: bool = False


class MuxConfig(Strict):
    mode: Literal["priority", "takeover"] = "priority"
    topics: dict[Name, MuxTopic]
    locks: dict[Name, MuxTopic] = {}
    manual_takeover_seconds: Annotated[float, Field(ge=0, le=10)] = 0.5

    @model_validator(mode="after")
    def _names(self) -> MuxConfig:
        both = set(self.topics) & set(self.locks)
        if both:
            raise ValueError(f"names used as both topic and lock: {sorted(both)}")
        if "estop" in self.locks:
            raise ValueError("'estop' is built in (the highest lock); do not declare it")
        if self.mode == "takeover" and not {"manual", "auto"} <= set(self.topics):
            raise ValueError("takeover mode needs 'manual' and 'auto' topics")
        return self


class ControlConfig(Strict):
    tick_hz: Annotated[float, Field(ge=5, le=500)] = 100.0
    # Voltage/temperature/status are read round-robin, one servo per this many ticks.
    health_every_ticks: Annotated[int, Field(ge=1, le=1000)] = 10


class ApiConfig(Strict):
    host: str = "127.0.0.1"
    port: Annotated[int, Field(ge=0, le=65535)] = 8080
    token: str | None = None
    tls_cert: str | None = None
    tls_key: str | None = None
    state_hz: Annotated[float, Field(gt=0, le=100)] = 20.0
    max_body_bytes: Annotated[int, Field(ge=256, le=1_048_576)] = 16_384

    @model_validator(mode="after")
    def _tls_pair(self) -> ApiConfig:
        if (self.tls_cert is None) != (self.tls_key is None):
            raise ValueError("tls_cert and tls_key go together")
        return self


class RobotProfile(Strict):
    """A whole robot: bus, arm, base, presets, mux, control and API settings."""

    name: Name
    description: str = ""
    bus: BusConfig = BusConfig()
    control: ControlConfig = ControlConfig()
    arm: ArmConfig
    base: BaseConfig | None = None
    presets: dict[Name, dict[Name, float]] = {}
    mux: MuxConfig
    api: ApiConfig = ApiConfig()

    @field_validator("presets")
    @classmethod
    def _finite_presets(cls, value: dict[str, dict[str, float]]) -> dict[str, dict[str, float]]:
        for preset, pose in value.items():
            for joint, rad in pose.items():
                if not math.isfinite(rad):
                    raise ValueError(f"preset {preset!r}: {joint} is not a finite number")
        return value

    @model_validator(mode="after")
    def _cross_checks(self) -> RobotProfile:
        _check_joints(self.arm.joints)
        wheels = self.base.wheels if self.base else []
        _check_ids(self.arm.joints, wheels)
        names = {j.name for j in self.arm.joints}
        gripper = self.arm.gripper.joint if self.arm.gripper else None
        if gripper is not None and gripper not in names:
            raise ValueError(f"arm.gripper.joint: {gripper!r} is not an arm joint")
        for preset, pose in self.presets.items():
            for joint in pose:
                if joint not in names:
                    raise ValueError(f"presets.{preset}: {joint!r} is not an arm joint")
                if joint == gripper:
                    raise ValueError(
                        f"presets.{preset}: presets never move the gripper ({joint!r})"
                    )
        return self

    def joint(self, name: str) -> JointConfig:
        for j in self.arm.joints:
            if j.name == name:
                return j
        raise KeyError(name)


def _check_joints(joints: list[JointConfig]) -> None:
    for i, j in enumerate(joints):
        where = f"arm.joints[{i}] ({j.name})"
        if j.min >= j.max:
            raise ValueError(f"{where}.min: min {j.min} must be below max {j.max}")
        if not j.min <= j.zero <= j.max:
            raise ValueError(f"{where}.zero: {j.zero} is outside its limits [{j.min}, {j.max}]")


def _check_ids(joints: list[JointConfig], wheels: list[WheelConfig]) -> None:
    # An arm id equal to a wheel id would send arm goals to a wheel (bring-up seed).
    seen: dict[int, str] = {}
    seen_names: set[str] = set()
    entries: list[tuple[str, JointConfig | WheelConfig]] = [
        *((f"arm.joints[{i}]", j) for i, j in enumerate(joints)),
        *((f"base.wheels[{i}]", w) for i, w in enumerate(wheels)),
    ]
    for label, item in entries:
        where = f"{label} ({item.name})"
        if item.id in seen:
            raise ValueError(f"{where}.id: id {item.id} is already used by {seen[item.id]}")
        if item.name in seen_names:
            raise ValueError(f"{where}.name: duplicate name {item.name!r}")
        seen[item.id] = where
        seen_names.add(item.name)


class JointOverlay(Strict):
    """One joint's measured calibration in ``$LUPIN_HOME/arm.yaml``."""

    zero: Counts
    min: Counts
    max: Counts
    # How the values were measured (swept range, samples, margin, offset written).
    measurement: dict[str, Any] = {}


class ArmOverlay(Strict):
    joints: dict[Name, JointOverlay] = {}
