"""``/api/ws``: hello, state push, twists, commands, malformed frames, limits, heartbeat."""

from __future__ import annotations

import asyncio
import json
from typing import Any

import aiohttp
import pytest

from lupin.api import ApiServer
from lupin.api.frames import HelloFrame, StateFrame
from lupin.api.ws import WsSettings
from lupin.daemon import Daemon
from lupintest.harness import wait_for

from .conftest import start_api


async def next_not_state(ws: aiohttp.ClientWebSocketResponse, timeout: float = 3.0) -> Any:
    """The next frame that is not a state push."""
    async with asyncio.timeout(timeout):
        while True:
            frame = await ws.receive_json()
            if frame["type"] != "state":
                return frame


async def command(ws: aiohttp.ClientWebSocketResponse, frame: dict[str, Any]) -> Any:
    await ws.send_json(frame)
    reply = await next_not_state(ws)
    assert reply["type"] == "reply" and reply["id"] == frame["id"], reply
    return reply


async def test_hello_then_state_at_about_20_hz(http: aiohttp.ClientSession, api: ApiServer) -> None:
    async with http.ws_connect(api.url + "/api/ws") as ws:
        hello = HelloFrame.model_validate(await ws.receive_json(timeout=2))
        assert hello.profile == "so101" and hello.state_hz == 20.0
        loop = asyncio.get_running_loop()
        start, frames = loop.time(), []
        while loop.time() - start < 1.0:
            frames.append(StateFrame.model_validate(await ws.receive_json(timeout=2)))
        assert 10 <= len(frames) <= 30
        stamps = [f.t for f in frames]
        assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)


async def test_twist_without_id_is_silent_with_id_is_answered(
    http: aiohttp.ClientSession, api: ApiServer, daemon: Daemon
) -> None:
    async with http.ws_connect(api.url + "/api/ws") as ws:
        await ws.receive_json(timeout=2)
        await ws.send_json({"type": "twist", "source": "manual", "linear_x": 0.1})
        await wait_for(lambda: daemon.mux.status(daemon.clock()).active == "manual", 1.0)
        reply = await command(ws, {"type": "twist", "source": "manual", "id": "t1"})
        assert reply == {"type": "reply", "id": "t1", "ok": True, "result": {"ok": True}}
        # A client that stops sending its twists simply times out in the mux (0.5 s).
        await wait_for(lambda: daemon.mux.status(daemon.clock()).active is None, 2.0)


async def test_commands_with_ids(
    http: aiohttp.ClientSession, api: ApiServer, daemon: Daemon
) -> None:
    async with http.ws_connect(api.url + "/api/ws") as ws:
        await ws.receive_json(timeout=2)
        r = await command(ws, {"type": "joint", "id": 1, "joint": "elbow_flex", "angle_deg": 5})
        assert r["ok"] is False and r["error"]["code"] == "torque_off"
        r = await command(ws, {"type": "torque", "id": 2, "enabled": True})
        assert r["result"] == {"torque": "on"}
        r = await command(
            ws, {"type": "joint", "id": 3, "joint": "elbow_flex", "angle_deg": 5, "speed_deg_s": 50}
        )
        assert r["ok"] and r["result"]["targets_deg"] == {"elbow_flex": pytest.approx(5.0)}
        r = await command(ws, {"type": "gripper", "id": 4, "angle_deg": -10})
        assert r["ok"] and r["result"]["targets_deg"] == {"gripper": -10.0}
        r = await command(ws, {"type": "preset", "id": 5, "name": "inspect"})
        assert r["ok"] and r["result"]["travel_s"] == pytest.approx(3.0)
        r = await command(ws, {"type": "init", "id": 6})
        assert r["ok"]
        r = await command(ws, {"type": "pose_go", "id": 7, "name": "nope"})
        assert r["ok"] is False and r["error"]["code"] == "unknown_pose"
        r = await command(ws, {"type": "preset", "id": 8, "name": "nope"})
        assert r["error"]["code"] == "unknown_preset"
        r = await command(ws, {"type": "joint", "id": 9, "joint": "knee", "angle_deg": 5})
        assert r["error"]["code"] == "unknown_joint"
        r = await command(ws, {"type": "estop", "id": "e", "engaged": True})
        assert r["result"] == {"engaged": True} and daemon.estop
        r = await command(ws, {"type": "heal", "id": 10})
        assert r["ok"] and r["result"]["result"] in ("healthy", "healed")
        r = await command(ws, {"type": "torque", "id": 11, "enabled": False})
        assert r["result"] == {"torque": "off"}


async def test_malformed_frames_get_errors_and_the_socket_stays(
    http: aiohttp.ClientSession, api: ApiServer, daemon: Daemon
) -> None:
    async with http.ws_connect(api.url + "/api/ws") as ws:
        await ws.receive_json(timeout=2)
        cases: list[tuple[str | bytes, str, str]] = [
            ("not json", "invalid_json", ""),
            ("[1, 2]", "invalid_frame", "JSON object"),
            ('{"type": "dance"}', "invalid_frame", "dance"),
            ('{"angle_deg": 1}', "invalid_frame", "type"),
            ('{"type": "twist", "source": "manual", "linear_x": NaN}', "invalid_json", "NaN"),
            ('{"type": "twist", "source": "manual", "linear_x": 9}', "invalid_frame", "linear_x"),
            ('{"type": "estop", "engaged": true, "extra": 1}', "invalid_frame", "extra"),
            (b"\x00\x01", "invalid_frame", "text"),
        ]
        for raw, code, needle in cases:
            if isinstance(raw, bytes):
                await ws.send_bytes(raw)
            else:
                await ws.send_str(raw)
            frame = await next_not_state(ws)
            assert frame["type"] == "error" and frame["error"]["code"] == code, (raw, frame)
            assert needle in frame["error"]["message"], (raw, frame)
        # With a readable id, a refusal is a reply naming the field.
        reply = await command(ws, {"type": "joint", "id": "j", "joint": "elbow_flex"})
        assert reply["ok"] is False and reply["error"]["code"] == "invalid_frame"
        assert "angle_deg" in reply["error"]["message"]
        assert not daemon.estop
        reply = await command(ws, {"type": "estop", "id": "ok", "engaged": True})
        assert reply["ok"] is True


async def test_rate_limit_drops_the_excess(http: aiohttp.ClientSession, api: ApiServer) -> None:
    async with http.ws_connect(api.url + "/api/ws") as ws:
        await ws.receive_json(timeout=2)
        for i in range(120):
            await ws.send_json({"type": "twist", "source": "manual", "id": i})
        replies = []
        while len(replies) < 120:
            replies.append(await next_not_state(ws))
        limited = [r for r in replies if r.get("error", {}).get("code") == "rate_limited"]
        accepted = [r for r in replies if r.get("ok") is True]
        assert 50 <= len(accepted) < 120 and len(limited) == 120 - len(accepted)
        assert all(r["id"] is not None for r in limited)  # still matched to their frames
        await asyncio.sleep(0.2)  # the bucket refills
        assert (await command(ws, {"type": "twist", "source": "manual", "id": "x"}))["ok"]


async def test_oversized_frame_closes_only_that_socket(
    http: aiohttp.ClientSession, api: ApiServer
) -> None:
    async with http.ws_connect(api.url + "/api/ws") as other:
        await other.receive_json(timeout=2)
        async with http.ws_connect(api.url + "/api/ws") as ws:
            await ws.receive_json(timeout=2)
            pad = "x" * (api.config.max_body_bytes + 1)
            await ws.send_str(json.dumps({"type": "twist", "source": "manual", "pad": pad}))
            async with asyncio.timeout(3):
                while (msg := await ws.receive()).type is aiohttp.WSMsgType.TEXT:
                    pass
            assert msg.type is aiohttp.WSMsgType.CLOSE
            assert msg.data == aiohttp.WSCloseCode.MESSAGE_TOO_BIG
        assert (await other.receive_json(timeout=2))["type"] == "state"
    await wait_for(lambda: not api.hub.connections, 2.0)


async def test_heartbeat_closes_a_dead_client(http: aiohttp.ClientSession, daemon: Daemon) -> None:
    server = await start_api(daemon, ws=WsSettings(heartbeat_s=0.3))
    hub = server.hub
    try:
        # autoping off and never reading: no pong ever comes back, as from a dead peer.
        dead = await http.ws_connect(server.url + "/api/ws", autoping=False)
        await wait_for(lambda: len(hub.connections) == 1, 2.0)
        (dead_conn,) = hub.connections
        async with http.ws_connect(server.url + "/api/ws") as alive:
            states = 0

            async def keep_reading() -> None:  # reading is what answers the pings
                nonlocal states
                async for msg in alive:
                    states += json.loads(msg.data)["type"] == "state"

            reading = asyncio.create_task(keep_reading())
            await wait_for(lambda: len(hub.connections) == 2, 2.0)
            await wait_for(lambda: dead_conn not in hub.connections, 5.0)
            seen = states
            await asyncio.sleep(1.0)  # several heartbeats later the live client is still fed
            assert len(hub.connections) == 1 and states > seen
            await alive.close()
            await reading
        await dead.close()
    finally:
        await server.stop()


async def test_stop_closes_clients_going_away(http: aiohttp.ClientSession, daemon: Daemon) -> None:
    server = await start_api(daemon)
    ws = await http.ws_connect(server.url + "/api/ws")
    await ws.receive_json(timeout=2)
    await server.stop()
    async with asyncio.timeout(3):
        while (msg := await ws.receive()).type is aiohttp.WSMsgType.TEXT:
            pass
    assert msg.type is aiohttp.WSMsgType.CLOSE and msg.data == aiohttp.WSCloseCode.GOING_AWAY
    await ws.close()
