"""WebSocket frames: what a client may send on ``/api/ws`` and what the server sends back.

Every client command is the HTTP request model plus ``type`` (and ``id``, and
the path parameter such as ``joint`` or ``name``), so a frame and its HTTP
twin are validated by the same rules. The models subclass the request models,
which lets a validated frame be handed to the service method as the request.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter

from lupin import api_models as m

FrameId = Annotated[str, Field(max_length=64)] | Annotated[int, Field(ge=0, le=2**53)]
Name = Annotated[str, Field(min_length=1, max_length=64)]


class Command(m.Request):
    id: FrameId | None = None


class AuthFrame(Command):
    """First frame when the daemon has a token and the upgrade carried none."""

    type: Literal["auth"]
    token: Annotated[str, Field(max_length=512)]


class TwistFrame(m.TwistRequest, Command):
    """A manual/auto twist; answered only when it carries an ``id`` or is refused."""

    type: Literal["twist"]


class EstopFrame(m.EstopRequest, Command):
    type: Literal["estop"]


class JointFrame(m.JointRequest, Command):
    type: Literal["joint"]
    joint: Name


class GripperFrame(m.JointRequest, Command):
    type: Literal["gripper"]


class TorqueFrame(m.TorqueRequest, Command):
    type: Literal["torque"]


class InitFrame(Command):
    type: Literal["init"]


class PresetFrame(Command):
    type: Literal["preset"]
    name: Name


class PoseGoFrame(m.PoseGoRequest, Command):
    type: Literal["pose_go"]
    name: Name


class HealFrame(Command):
    type: Literal["heal"]


ClientFrame = Annotated[
    AuthFrame
    | TwistFrame
    | EstopFrame
    | JointFrame
    | GripperFrame
    | TorqueFrame
    | InitFrame
    | PresetFrame
    | PoseGoFrame
    | HealFrame,
    Field(discriminator="type"),
]
CLIENT_FRAME: TypeAdapter[ClientFrame] = TypeAdapter(ClientFrame)


# -- server frames (documentation and tests; the state frame is spliced, see broadcast) --


class ServerFrame(BaseModel):
    model_config = ConfigDict(extra="forbid")


class HelloFrame(m.RobotInfo):
    """Sent once, right after connect (or after a successful ``auth`` frame)."""

    type: Literal["hello"]


class StateFrame(m.RobotState):
    """Pushed at ``api.state_hz``; a client that falls behind gets only the newest."""

    type: Literal["state"]


class ReplyFrame(ServerFrame):
    """The answer to a frame that carried an ``id``: ``result`` or ``error``."""

    type: Literal["reply"]
    id: FrameId
    ok: bool
    result: dict[str, Any] | None = None
    error: m.ErrorBody | None = None


class ErrorFrame(ServerFrame):
    """A refusal of a frame without an ``id`` (malformed, rate limited, not authenticated)."""

    type: Literal["error"]
    error: m.ErrorBody


FRAME_MODELS: tuple[type[BaseModel], ...] = (
    AuthFrame,
    TwistFrame,
    EstopFrame,
    JointFrame,
    GripperFrame,
    TorqueFrame,
    InitFrame,
    PresetFrame,
    PoseGoFrame,
    HealFrame,
    HelloFrame,
    StateFrame,
    ReplyFrame,
    ErrorFrame,
)
