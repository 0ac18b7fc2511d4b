"""The service endpoints of SPEC §5 as a table: one row per method and path.

The same rows register the aiohttp routes and generate the OpenAPI document,
so an endpoint cannot exist without being described, nor be described with a
body it does not validate. Each row names its request model (validated
strictly before the service is called), its response model and the error
statuses it can answer.
"""

from __future__ import annotations

import re
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass
from typing import Any

from aiohttp import web
from pydantic import BaseModel

from lupin import api_models as m
from lupin.api.bodies import read_model, read_no_body
from lupin.api.contract import ApiServices
from lupin.api.errors import ApiError

Params = Mapping[str, str]
Call = Callable[[ApiServices, Params, Any], Awaitable[BaseModel]]

POSE_NAME = re.compile(r"^[A-Za-z0-9_-]{1,40}$")  # api_models.PoseName
BODY_ERRORS = (400, 413, 415)
MUTATION_ERRORS = (401, 403)


@dataclass(frozen=True)
class Route:
    method: str
    path: str
    summary: str
    call: Call
    response: type[BaseModel]
    request: type[BaseModel] | None = None
    body_required: bool = True
    errors: tuple[int, ...] = ()
    tag: str = "robot"

    @property
    def mutating(self) -> bool:
        return self.method in ("POST", "PUT", "DELETE")

    def error_statuses(self) -> list[int]:
        codes = set(self.errors)
        if self.mutating:
            codes |= {*MUTATION_ERRORS, *BODY_ERRORS}  # a body-less endpoint refuses a body
        return sorted(codes)


def _pose(params: Params) -> str:
    name = params["pose"]
    if not POSE_NAME.match(name):
        raise ApiError(400, "bad_name", f"pose names are 1-40 of A-Z a-z 0-9 _ -, not {name!r}")
    return name


# -- calls: path parameters and the validated body in, a response model out --------


async def _health(svc: ApiServices, p: Params, body: None) -> BaseModel:
    return svc.health()


async def _state(svc: ApiServices, p: Params, body: None) -> BaseModel:
    return svc.state()


async def _robot(svc: ApiServices, p: Params, body: None) -> BaseModel:
    return svc.robot()


async def _twist(svc: ApiServices, p: Params, body: m.TwistRequest) -> BaseModel:
    return svc.submit_twist(body)


async def _estop(svc: ApiServices, p: Params, body: m.EstopRequest) -> BaseModel:
    return await svc.set_estop(body)


async def _joint(svc: ApiServices, p: Params, body: m.JointRequest) -> BaseModel:
    return await svc.set_joint(p["joint"], body)


async def _gripper(svc: ApiServices, p: Params, body: m.JointRequest) -> BaseModel:
    return await svc.set_gripper(body)


async def _torque(svc: ApiServices, p: Params, body: m.TorqueRequest) -> BaseModel:
    return await svc.set_torque(body)


async def _init(svc: ApiServices, p: Params, body: None) -> BaseModel:
    return await svc.init_arm()


async def _presets(svc: ApiServices, p: Params, body: None) -> BaseModel:
    return svc.list_presets()


async def _go_preset(svc: ApiServices, p: Params, body: None) -> BaseModel:
    return await svc.go_preset(p["preset"])


async def _poses(svc: ApiServices, p: Params, body: None) -> BaseModel:
    return svc.list_poses()


async def _get_pose(svc: ApiServices, p: Params, body: None) -> BaseModel:
    return svc.get_pose(_pose(p))


async def _save_pose(svc: ApiServices, p: Params, body: m.PoseSaveRequest) -> BaseModel:
    return await svc.save_pose(_pose(p), body)


async def _delete_pose(svc: ApiServices, p: Params, body: None) -> BaseModel:
    return svc.delete_pose(_pose(p))


async def _go_pose(svc: ApiServices, p: Params, body: m.PoseGoRequest) -> BaseModel:
    return await svc.go_pose(_pose(p), body)


async def _heal(svc: ApiServices, p: Params, body: None) -> BaseModel:
    return await svc.heal()


# 404 unknown name, 409 refused by state (torque off, E-stop, not seeded), 503 bus down.
REFUSALS = (404, 409, 503)

ROUTES: tuple[Route, ...] = (
    Route("GET", "/api/health", "Liveness and bus summary", _health, m.HealthResponse, tag="read"),
    Route(
        "GET",
        "/api/state",
        "Joints, torque, E-stop, mux, base, pad",
        _state,
        m.RobotState,
        tag="read",
    ),
    Route(
        "GET",
        "/api/robot",
        "Profile: joints with windows, presets, pad layout, mux sources",
        _robot,
        m.RobotInfo,
        tag="read",
    ),
    Route(
        "POST",
        "/api/base/twist",
        "Submit a manual or auto twist to the velocity mux",
        _twist,
        m.Ok,
        m.TwistRequest,
        errors=(404,),
        tag="base",
    ),
    Route(
        "POST",
        "/api/estop",
        "Engage or release the E-stop",
        _estop,
        m.EstopResponse,
        m.EstopRequest,
        tag="base",
    ),
    Route(
        "POST",
        "/api/arm/joints/{joint}",
        "Move one joint: target and travel time",
        _joint,
        m.MoveResponse,
        m.JointRequest,
        errors=REFUSALS,
        tag="arm",
    ),
    Route(
        "POST",
        "/api/arm/gripper",
        "Move the gripper (HMI degrees)",
        _gripper,
        m.MoveResponse,
        m.JointRequest,
        errors=REFUSALS,
        tag="arm",
    ),
    Route(
        "POST",
        "/api/arm/torque",
        "Enable (seeded, no lurch) or disable arm torque",
        _torque,
        m.TorqueResponse,
        m.TorqueRequest,
        errors=(409, 503),
        tag="arm",
    ),
    Route(
        "POST",
        "/api/arm/init",
        "Drive the arm to zero",
        _init,
        m.MoveResponse,
        errors=REFUSALS,
        tag="arm",
    ),
    Route(
        "GET", "/api/arm/presets", "List the presets (degrees)", _presets, m.PresetList, tag="arm"
    ),
    Route(
        "POST",
        "/api/arm/presets/{preset}",
        "Move to a preset (never the gripper)",
        _go_preset,
        m.MoveResponse,
        errors=REFUSALS,
        tag="arm",
    ),
    Route(
        "GET",
        "/api/arm/poses",
        "List the taught poses",
        _poses,
        m.PoseList,
        errors=(409,),
        tag="poses",
    ),
    Route(
        "GET",
        "/api/arm/poses/{pose}",
        "One taught pose",
        _get_pose,
        m.Pose,
        errors=(400, 404, 409),
        tag="poses",
    ),
    Route(
        "PUT",
        "/api/arm/poses/{pose}",
        "Teach a pose: capture the measured pose or store the given joints",
        _save_pose,
        m.Pose,
        m.PoseSaveRequest,
        body_required=False,
        errors=REFUSALS,
        tag="poses",
    ),
    Route(
        "DELETE",
        "/api/arm/poses/{pose}",
        "Forget a taught pose",
        _delete_pose,
        m.Ok,
        errors=(404, 409),
        tag="poses",
    ),
    Route(
        "POST",
        "/api/arm/poses/{pose}/go",
        "Go to a taught pose (travel guard, streamed)",
        _go_pose,
        m.PoseGoResponse,
        m.PoseGoRequest,
        body_required=False,
        errors=REFUSALS,
        tag="poses",
    ),
    Route(
        "POST",
        "/api/heal",
        "Re-run heal and auto-home; the tri-state result",
        _heal,
        m.HealResponse,
        errors=(409, 503),
        tag="heal",
    ),
)

SERVICES_KEY: web.AppKey[ApiServices] = web.AppKey("services")


def handler_for(route: Route) -> Callable[[web.Request], Awaitable[web.Response]]:
    async def handle(request: web.Request) -> web.Response:
        body: BaseModel | None = None
        if route.request is not None:
            body = await read_model(request, route.request)
        elif route.mutating:
            await read_no_body(request)
        result = await route.call(request.app[SERVICES_KEY], request.match_info, body)
        return web.Response(text=result.model_dump_json(), content_type="application/json")

    handle.__name__ = f"handle_{route.call.__name__.lstrip('_')}"
    return handle


def add_routes(app: web.Application) -> None:
    for route in ROUTES:
        # HEAD is not part of the contract; leave it out so the OpenAPI document is complete.
        if route.method == "GET":
            app.router.add_get(route.path, handler_for(route), allow_head=False)
        else:
            app.router.add_route(route.method, route.path, handler_for(route))
