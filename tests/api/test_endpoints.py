"""Every endpoint of SPEC §5, its success and its refusals, against the real daemon on the sim."""

from __future__ import annotations

import asyncio

import aiohttp
import pytest

from lupin import api_models as m
from lupin.api import ApiServer
from lupin.daemon import Daemon
from lupintest.harness import Sim

from .helpers import call, error_code, torque_on

pytestmark = pytest.mark.usefixtures("api")


# -- reads -------------------------------------------------------------------------


async def test_health(http: aiohttp.ClientSession, api: ApiServer) -> None:
    status, data = await call(http, api, "GET", "/api/health")
    assert status == 200
    health = m.HealthResponse.model_validate(data)
    assert health.ok and health.profile == "so101" and health.tick_hz == 100.0


async def test_state(http: aiohttp.ClientSession, api: ApiServer) -> None:
    status, data = await call(http, api, "GET", "/api/state")
    assert status == 200
    state = m.RobotState.model_validate(data)
    assert [j.name for j in state.joints][:2] == ["shoulder_pan", "shoulder_lift"]
    assert state.torque == "off" and not state.estop and state.seeded
    assert all(j.position_deg is not None for j in state.joints)


async def test_robot(http: aiohttp.ClientSession, api: ApiServer) -> None:
    status, data = await call(http, api, "GET", "/api/robot")
    assert status == 200
    robot = m.RobotInfo.model_validate(data)
    assert len(robot.joints) == 6 and robot.gripper is not None
    assert {"home", "zero", "tuck", "pick", "place", "inspect"} <= set(robot.presets)
    assert robot.state_hz == 20.0 and "manual" in robot.mux_sources


async def test_unknown_path_is_404_with_error_body(
    http: aiohttp.ClientSession, api: ApiServer
) -> None:
    status, data = await call(http, api, "GET", "/api/nope")
    assert status == 404 and error_code(data) == "not_found"


async def test_wrong_method_is_405_with_allow_and_error_body(
    http: aiohttp.ClientSession, api: ApiServer
) -> None:
    async with http.patch(api.url + "/api/estop", json={"engaged": True}) as resp:
        assert resp.status == 405
        assert resp.headers["Allow"] == "POST"
        assert error_code(await resp.json()) == "method_not_allowed"
    status, data = await call(http, api, "GET", "/api/estop")
    assert status == 405 and error_code(data) == "method_not_allowed"


# -- base and E-stop ---------------------------------------------------------------------


async def test_twist_goes_through_the_mux(
    http: aiohttp.ClientSession, api: ApiServer, daemon: Daemon
) -> None:
    body = {"source": "manual", "linear_x": 0.1, "angular_z": 0.2}
    assert await call(http, api, "POST", "/api/base/twist", body) == (200, {"ok": True})
    await asyncio.sleep(0.05)  # the base takes the mux output at the next tick
    _status, data = await call(http, api, "GET", "/api/state")
    assert data["mux"]["active"] == "manual"
    assert data["base"]["twist"] == {"linear_x": 0.1, "linear_y": 0.0, "angular_z": 0.2}


async def test_twist_refusals(
    http: aiohttp.ClientSession, api: ApiServer, daemon: Daemon, monkeypatch: pytest.MonkeyPatch
) -> None:
    status, data = await call(http, api, "POST", "/api/base/twist", {"source": "joy"})
    assert status == 400 and "source" in data["error"]["message"]  # joy is the pad's alone
    body = {"source": "manual", "linear_x": 9.0}
    status, data = await call(http, api, "POST", "/api/base/twist", body)
    assert status == 400 and "linear_x" in data["error"]["message"]
    # A source the model allows but this robot's mux does not have: 404.
    monkeypatch.setattr(daemon, "mux_sources", lambda: ["manual"])
    status, data = await call(http, api, "POST", "/api/base/twist", {"source": "auto"})
    assert status == 404 and error_code(data) == "unknown_source"
    assert daemon.mux.status(daemon.clock()).active is None


async def test_estop_engage_and_release(
    http: aiohttp.ClientSession, api: ApiServer, daemon: Daemon
) -> None:
    assert await call(http, api, "POST", "/api/estop", {"engaged": True}) == (
        200,
        {"engaged": True},
    )
    assert daemon.estop
    _, state = await call(http, api, "GET", "/api/state")
    assert state["estop"] is True and state["mux"]["locked_by"] == "estop"
    assert await call(http, api, "POST", "/api/estop", {"engaged": False}) == (
        200,
        {"engaged": False},
    )
    assert not daemon.estop


async def test_estop_needs_a_bool(http: aiohttp.ClientSession, api: ApiServer) -> None:
    for body in ({}, {"engaged": "yes"}, {"engaged": 1}, {"engaged": None}):
        status, data = await call(http, api, "POST", "/api/estop", body)
        assert status == 400 and "engaged" in data["error"]["message"], body


# -- arm ---------------------------------------------------------------------------------


async def test_joint_refused_while_torque_off_then_moves(
    http: aiohttp.ClientSession, api: ApiServer, daemon: Daemon
) -> None:
    body = {"angle_deg": 10.0, "speed_deg_s": 60.0}
    status, data = await call(http, api, "POST", "/api/arm/joints/elbow_flex", body)
    assert status == 409 and error_code(data) == "torque_off"
    await torque_on(http, api)
    status, data = await call(http, api, "POST", "/api/arm/joints/elbow_flex", body)
    assert status == 200
    move = m.MoveResponse.model_validate(data)
    assert move.targets_deg == {"elbow_flex": pytest.approx(10.0)}
    assert move.travel_s == pytest.approx(10.0 / 60.0, abs=0.02)
    _, state = await call(http, api, "GET", "/api/state")
    elbow = next(j for j in state["joints"] if j["name"] == "elbow_flex")
    assert elbow["target_deg"] == pytest.approx(10.0)


async def test_joint_refusals(http: aiohttp.ClientSession, api: ApiServer, daemon: Daemon) -> None:
    await torque_on(http, api)
    cases = [
        ("/api/arm/joints/nope", {"angle_deg": 1.0}, 404, "unknown_joint"),
        ("/api/arm/joints/elbow_flex", {"angle_deg": 500.0}, 400, "out_of_window"),
        ("/api/arm/joints/elbow_flex", {"angle_deg": 1.0, "speed_deg_s": 0}, 400, None),
        ("/api/arm/joints/elbow_flex", {"angle_deg": "1"}, 400, None),
        ("/api/arm/joints/gripper", {"angle_deg": 1.0}, 400, "use_gripper"),
    ]
    before = dict(daemon.arm.commanded or {})
    for path, body, want, code in cases:
        status, data = await call(http, api, "POST", path, body)
        assert status == want, (path, body, data)
        if code is not None:
            assert error_code(data) == code
    assert daemon.arm.commanded == before
    # The E-stop refuses motion with 409.
    await call(http, api, "POST", "/api/estop", {"engaged": True})
    status, data = await call(http, api, "POST", "/api/arm/joints/elbow_flex", {"angle_deg": 5.0})
    assert status == 409 and error_code(data) == "estop"


async def test_gripper(http: aiohttp.ClientSession, api: ApiServer) -> None:
    status, data = await call(http, api, "POST", "/api/arm/gripper", {"angle_deg": 10.0})
    assert status == 409
    await torque_on(http, api)
    status, data = await call(http, api, "POST", "/api/arm/gripper", {"angle_deg": 10.0})
    assert status == 200 and data["targets_deg"] == {"gripper": 10.0}
    status, data = await call(http, api, "POST", "/api/arm/gripper", {"angle_deg": 90.0})
    assert status == 400 and error_code(data) == "out_of_window"


async def test_torque_on_off_and_refused_under_estop(
    http: aiohttp.ClientSession, api: ApiServer, sim: Sim
) -> None:
    await torque_on(http, api)
    assert all(sim.bus.servo(i).torque for i in range(1, 7))
    status, data = await call(http, api, "POST", "/api/arm/torque", {"enabled": False})
    assert (status, data) == (200, {"torque": "off"})
    assert not any(sim.bus.servo(i).torque for i in range(1, 7))
    await call(http, api, "POST", "/api/estop", {"engaged": True})
    status, data = await call(http, api, "POST", "/api/arm/torque", {"enabled": True})
    assert status == 409 and error_code(data) == "estop"
    assert not any(sim.bus.servo(i).torque for i in range(1, 7))


async def test_init_drives_to_zero(http: aiohttp.ClientSession, api: ApiServer) -> None:
    status, data = await call(http, api, "POST", "/api/arm/init")
    assert status == 409 and error_code(data) == "torque_off"
    await torque_on(http, api)
    status, data = await call(http, api, "POST", "/api/arm/init")
    assert status == 200
    assert set(data["targets_deg"].values()) == {0.0} and "gripper" not in data["targets_deg"]
    status, data = await call(http, api, "POST", "/api/arm/init", {"extra": 1})
    assert status == 400 and error_code(data) == "invalid_body"


async def test_presets(http: aiohttp.ClientSession, api: ApiServer) -> None:
    status, data = await call(http, api, "GET", "/api/arm/presets")
    assert status == 200
    presets = m.PresetList.model_validate(data).presets
    assert presets["home"]["wrist_flex"] == pytest.approx(-89.954, abs=0.01)
    status, data = await call(http, api, "POST", "/api/arm/presets/tuck")
    assert status == 409
    await torque_on(http, api)
    status, data = await call(http, api, "POST", "/api/arm/presets/tuck")
    assert status == 200 and data["travel_s"] == pytest.approx(3.0)
    assert "gripper" not in data["targets_deg"]  # presets never move the gripper
    status, data = await call(http, api, "POST", "/api/arm/presets/nope")
    assert status == 404 and error_code(data) == "unknown_preset"


async def test_poses_lifecycle(http: aiohttp.ClientSession, api: ApiServer, sim: Sim) -> None:
    assert await call(http, api, "GET", "/api/arm/poses") == (200, {"poses": []})
    status, data = await call(http, api, "PUT", "/api/arm/poses/rest")
    assert status == 200
    pose = m.Pose.model_validate(data)
    assert pose.name == "rest" and "elbow_flex" in pose.joints_rad
    status, data = await call(
        http, api, "PUT", "/api/arm/poses/bent", {"joints_rad": {"elbow_flex": 0.2}}
    )
    assert status == 200 and data["joints_rad"] == {"elbow_flex": 0.2}
    status, data = await call(http, api, "GET", "/api/arm/poses")
    assert [p["name"] for p in data["poses"]] == ["bent", "rest"]
    assert (await call(http, api, "GET", "/api/arm/poses/bent"))[1]["name"] == "bent"
    # go: refused with torque off, then too far for a small max travel, then moves.
    status, data = await call(http, api, "POST", "/api/arm/poses/bent/go")
    assert status == 409 and error_code(data) == "torque_off"
    await torque_on(http, api)
    status, data = await call(http, api, "POST", "/api/arm/poses/bent/go", {"max_travel_rad": 0.1})
    assert status == 409 and error_code(data) == "too_far"
    status, data = await call(http, api, "POST", "/api/arm/poses/bent/go", {"speed_rad_s": 1.0})
    assert status == 200
    go = m.PoseGoResponse.model_validate(data)
    assert go.largest_travel_rad == pytest.approx(0.2, abs=0.01)
    assert await call(http, api, "DELETE", "/api/arm/poses/bent") == (200, {"ok": True})
    status, data = await call(http, api, "DELETE", "/api/arm/poses/bent")
    assert status == 404 and error_code(data) == "unknown_pose"


async def test_pose_refusals(http: aiohttp.ClientSession, api: ApiServer) -> None:
    status, data = await call(http, api, "GET", "/api/arm/poses/nope")
    assert status == 404 and error_code(data) == "unknown_pose"
    status, data = await call(http, api, "PUT", "/api/arm/poses/bad%20name")
    assert status == 400 and error_code(data) == "bad_name"
    status, data = await call(
        http, api, "PUT", "/api/arm/poses/x", {"joints_rad": {"elbow_flex": "0.2"}}
    )
    assert status == 400 and "joints_rad.elbow_flex" in data["error"]["message"]
    status, data = await call(http, api, "PUT", "/api/arm/poses/x", {"joints_rad": {"knee": 0.2}})
    assert status == 404 and error_code(data) == "unknown_joint"
    status, data = await call(http, api, "POST", "/api/arm/poses/x/go", {"max_travel_rad": -1})
    assert status == 400 and "max_travel_rad" in data["error"]["message"]
    assert await call(http, api, "GET", "/api/arm/poses") == (200, {"poses": []})


async def test_heal(http: aiohttp.ClientSession, api: ApiServer) -> None:
    status, data = await call(http, api, "POST", "/api/heal")
    assert status == 200
    assert m.HealResponse.model_validate(data).result in ("healthy", "healed")


# -- the HMI -----------------------------------------------------------------------------


async def test_hmi_index_and_static(http: aiohttp.ClientSession, api: ApiServer) -> None:
    async with http.get(api.url + "/") as resp:
        assert resp.status == 200 and resp.content_type == "text/html"
        assert "<html" in (await resp.text()).lower()
        assert resp.headers["X-Frame-Options"] == "DENY"
    async with http.get(api.url + "/static/index.html") as resp:
        assert resp.status == 200
    for bad in ("/static/nope.js", "/static/..%2F__init__.py", "/static/.hidden"):
        status, data = await call(http, api, "GET", bad)
        assert status == 404 and error_code(data) == "not_found", bad


# -- nothing changes on an error --------------------------------------------------------


async def test_bad_requests_change_nothing_and_send_nothing(
    http: aiohttp.ClientSession, api: ApiServer, daemon: Daemon, sim: Sim
) -> None:
    await torque_on(http, api)
    await asyncio.sleep(0.1)  # let the enable sequence's writes settle
    t0 = asyncio.get_running_loop().time()  # the sim stamps packets with the loop clock
    before = (dict(daemon.arm.commanded or {}), daemon.estop, daemon.arm.torque_summary)
    bad = [
        ("POST", "/api/arm/joints/elbow_flex", {"angle_deg": 500.0}),
        ("POST", "/api/arm/joints/knee", {"angle_deg": 5.0}),
        ("POST", "/api/arm/gripper", {"angle_deg": 5.0, "force": 1}),
        ("POST", "/api/arm/presets/nope", None),
        ("POST", "/api/estop", {"engaged": "true"}),
        ("POST", "/api/base/twist", {"source": "manual", "linear_x": 100}),
        ("POST", "/api/arm/torque", {"enabled": False, "now": True}),
    ]
    for method, path, body in bad:
        status, _ = await call(http, api, method, path, body)
        assert 400 <= status < 500, (path, status)
    status, _ = await call(
        http, api, "POST", "/api/arm/joints/elbow_flex", raw='{"angle_deg": NaN}'
    )
    assert status == 400
    await asyncio.sleep(0.05)
    after = (dict(daemon.arm.commanded or {}), daemon.estop, daemon.arm.torque_summary)
    assert after == before
    assert daemon.mux.status(daemon.clock()).active is None
    assert sim.bus.writes(since=t0) == []  # an idle arm costs no write traffic, refused or not
