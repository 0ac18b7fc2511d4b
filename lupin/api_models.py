"""Request and response bodies of the service layer and the HTTP/WebSocket API.

One set of pydantic models serves three masters: the service layer returns
them, the API validates requests with them, and the OpenAPI document is
generated from them, so the contract cannot drift from the code. Angles are
degrees unless the field name ends in ``_rad``. Requests forbid unknown fields
and refuse NaN and infinities.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

Finite = Annotated[float, Field(allow_inf_nan=False)]
Speed = Annotated[float, Field(gt=0, le=720, allow_inf_nan=False)]
PoseName = Annotated[str, Field(pattern=r"^[A-Za-z0-9_-]{1,40}$")]
MIN_POSE_SPEED_RAD_S = 0.01


class Request(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class Response(BaseModel):
    model_config = ConfigDict(extra="forbid")


# -- requests ----------------------------------------------------------------------


class TwistRequest(Request):
    source: Literal["manual", "auto"]
    linear_x: Annotated[float, Field(ge=-2, le=2, allow_inf_nan=False)] = 0.0
    linear_y: Annotated[float, Field(ge=-2, le=2, allow_inf_nan=False)] = 0.0
    angular_z: Annotated[float, Field(ge=-6, le=6, allow_inf_nan=False)] = 0.0


class EstopRequest(Request):
    engaged: bool


class JointRequest(Request):
    angle_deg: Finite
    speed_deg_s: Speed | None = None


class TorqueRequest(Request):
    enabled: bool


class PoseGoRequest(Request):
    max_travel_rad: Annotated[float, Field(gt=0, le=6.3, allow_inf_nan=False)] = 0.35
    # A floor, not just > 0: the move is streamed as travel / speed * 20 Hz setpoints, so
    # 1e-12 rad/s asked for billions of them and froze the event loop, control tick
    # included, with the arm energised (found by the reliability suite's fuzzing).
    # 0.01 rad/s bounds a full-window move to ~13 000 setpoints (about 10 minutes).
    speed_rad_s: Annotated[float, Field(ge=MIN_POSE_SPEED_RAD_S, le=3.0, allow_inf_nan=False)] = 0.5


class PoseSaveRequest(Request):
    """PUT a pose: capture the current measured pose, or store the given joints (rad)."""

    # At least one joint: an empty pose has nothing to go to, and a move naming no joint
    # would pass the torque check vacuously (found by the reliability suite's fuzzing).
    joints_rad: Annotated[dict[str, Finite], Field(min_length=1)] | None = None


# -- responses -----------------------------------------------------------------------


class ErrorBody(Response):
    code: str
    message: str


class ErrorResponse(Response):
    error: ErrorBody


class Ok(Response):
    ok: bool = True


class MoveResponse(Response):
    """A motion accepted: where each joint is going and how long it takes."""

    targets_deg: dict[str, float]
    travel_s: float


class TorqueResponse(Response):
    torque: Literal["on", "off", "unknown", "enabling"]


class EstopResponse(Response):
    engaged: bool


class JointState(Response):
    name: str
    id: int
    position_deg: float | None
    velocity_deg_s: float | None
    load: int | None
    temperature_c: int | None
    voltage_v: float | None
    commanded_deg: float | None
    target_deg: float | None
    setpoint_deg: float | None = None  # what this tick drives the joint to (the ramp)
    status: Literal["idle", "moving", "settled", "stalled"]
    torque: Literal["on", "off", "unknown", "enabling"]
    excluded: str | None = None
    error_bits: int = 0
    stale: bool = False


class WheelState(Response):
    name: str
    id: int
    speed_counts_s: int | None
    goal_counts_s: int
    excluded: str | None = None
    error_bits: int = 0
    stale: bool = False  # missed the last read


class SourceState(Response):
    priority: int
    timeout: float
    age_s: float | None
    fresh: bool
    masked: bool


class MuxState(Response):
    mode: Literal["priority", "takeover"]
    active: str | None
    locked_by: str | None
    sources: dict[str, SourceState]


class BaseState(Response):
    twist: dict[str, float] | None
    wheels: list[WheelState]
    # Why the base refuses to drive (a wheel excluded or not answering), or None.
    blocked: str | None = None


class PadState(Response):
    connected: bool
    layout: str | None = None
    deadman: bool = False
    age_s: float | None = None


class StallEvent(Response):
    t: float
    joint: str
    error_deg: float
    diagnosis: str


class RobotState(Response):
    t: float
    joints: list[JointState]
    torque: Literal["on", "off", "unknown", "enabling"]
    estop: bool
    seeded: bool
    mux: MuxState
    base: BaseState | None
    pad: PadState
    events: list[StallEvent] = []


class JointInfo(Response):
    name: str
    id: int
    window_deg: tuple[int, int]
    is_gripper: bool = False


class GripperInfo(Response):
    joint: str
    hmi_open_deg: float
    hmi_closed_deg: float
    # The joint angles at the open and closed ends, so a measured jaw can be shown on the
    # HMI's open/close scale.
    open_rad: float
    closed_rad: float


class BaseInfo(Response):
    kind: Literal["differential", "mecanum"]
    holonomic: bool  # can strafe (linear_y)
    max_linear_m_s: float  # a wheel at its speed limit
    max_angular_rad_s: float


class RobotInfo(Response):
    profile: str
    description: str
    joints: list[JointInfo]
    gripper: GripperInfo | None
    base: BaseInfo | None = None
    presets: dict[str, dict[str, float]]  # degrees
    pad_layout: dict[str, object] | None
    mux_sources: dict[str, SourceState]
    default_speed_deg_s: float
    state_hz: float


class PresetList(Response):
    presets: dict[str, dict[str, float]]  # degrees


class Pose(Response):
    name: str
    joints_rad: dict[str, float]
    distance_rad: float | None = None  # largest joint distance from the current pose


class PoseList(Response):
    poses: list[Pose]


class PoseGoResponse(Response):
    name: str
    largest_travel_rad: float
    travel_s: float


class HealResponse(Response):
    result: Literal["healthy", "healed", "failed", "unknown"]
    details: list[str]
    auto_home: Literal["done", "skipped", "disabled", "failed", "pending"] | None = None


class HealthResponse(Response):
    ok: bool
    profile: str
    bus: dict[str, object]
    tick_hz: float
    uptime_s: float
