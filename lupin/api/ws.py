"""``/api/ws``: state frames out, twists and commands in, one connection per browser tab.

Protocol (docs/api.md has the full text):
* connect (with the token as subprotocol ``bearer.<token>``, or send
  ``{"type": "auth", "token": ...}`` first when the daemon has a token);
* the server sends ``{"type": "hello", ...robot info}``, then
  ``{"type": "state", ...}`` at ``api.state_hz``;
* the client sends ``{"type": "twist", "source": "manual", ...}`` (no reply unless
  it carries an ``id``) and commands with an ``id``, answered
  ``{"type": "reply", "id", "ok": true, "result"}`` or ``"ok": false, "error"``;
* a malformed frame is answered with an error (a reply when its ``id`` can be
  read) and the connection stays open; so does the server, always.

Each connection has a token-bucket message budget, a frame size limit and a
heartbeat (a client that stops answering pings is closed and forgotten).
Commands run as tasks, so a torque enable that takes a second does not hold up
the twists behind it; a connection may have only a few in flight.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

from aiohttp import WSCloseCode, WSMsgType, web
from pydantic import BaseModel

from lupin import api_models as m
from lupin.api import frames as f
from lupin.api.bodies import loads, validate_frame
from lupin.api.broadcast import Outbox, StateBroadcaster
from lupin.api.contract import ApiServices
from lupin.api.errors import ApiError
from lupin.api.ratelimit import TokenBucket
from lupin.api.security import (
    bearer_of,
    is_foreign_origin,
    subprotocol_token,
    token_matches,
    unauthorized,
)
from lupin.services import ServiceError

log = logging.getLogger(__name__)

PROTOCOL = "lupin.v1"
CLOSE_UNAUTHORIZED = 4401  # application close code: no or wrong token
STOP_GRACE_S = 0.5  # on shutdown, for clients to take their close frame and commands to end
R = TypeVar("R", bound=BaseModel)


@dataclass(frozen=True)
class WsSettings:
    state_hz: float = 20.0
    heartbeat_s: float = 5.0  # ping every 5 s; no pong within 2.5 s closes the socket
    max_msg_size: int = 16_384
    rate_per_s: float = 50.0
    burst: float = 50.0
    auth_timeout_s: float = 5.0
    max_in_flight: int = 8
    # Bytes a client may have in flight before its writer waits for the socket: what a
    # stalled client can cost the server, besides the one state frame in its outbox.
    writer_limit: int = 32_768


@dataclass(eq=False)
class Connection:
    ws: web.WebSocketResponse
    outbox: Outbox
    bucket: TokenBucket
    transport: asyncio.BaseTransport | None = None
    in_flight: set[asyncio.Task[Any]] = field(default_factory=set)

    def send(self, frame: str) -> None:
        if not self.ws.closed:
            self.outbox.offer_reply(frame)

    def reply(self, frame_id: Any, result: BaseModel) -> None:
        """``{"type": "reply", "id", "ok": true, "result"}``, only if the frame had an id."""
        if frame_id is not None:
            result_json = result.model_dump_json()
            self.send(
                f'{{"type":"reply","id":{json.dumps(frame_id)},"ok":true,"result":{result_json}}}'
            )

    def refuse(self, frame_id: Any, code: str, message: str) -> None:
        """A failed reply if the frame had a readable id, else an error frame."""
        error = m.ErrorBody(code=code, message=message).model_dump_json()
        if frame_id is None:
            self.send(f'{{"type":"error","error":{error}}}')
        else:
            self.send(f'{{"type":"reply","id":{json.dumps(frame_id)},"ok":false,"error":{error}}}')


def frame_id_of(data: Any) -> Any:
    """The ``id`` of a frame if it is a usable one, so even a refusal can be matched."""
    if not isinstance(data, dict):
        return None
    value = data.get("id")
    if isinstance(value, str) and len(value) <= 64:
        return value
    if isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= 2**53:
        return value
    return None


def _as(model: type[R], frame: BaseModel) -> R:
    """The HTTP request model inside a frame (drops ``type``, ``id`` and path fields)."""
    return model.model_validate(frame.model_dump(include=set(model.model_fields)))


CommandCall = Callable[[ApiServices, Any], Awaitable[BaseModel]]
COMMANDS: dict[type[BaseModel], CommandCall] = {
    f.EstopFrame: lambda s, fr: s.set_estop(_as(m.EstopRequest, fr)),
    f.JointFrame: lambda s, fr: s.set_joint(fr.joint, _as(m.JointRequest, fr)),
    f.GripperFrame: lambda s, fr: s.set_gripper(_as(m.JointRequest, fr)),
    f.TorqueFrame: lambda s, fr: s.set_torque(_as(m.TorqueRequest, fr)),
    f.InitFrame: lambda s, fr: s.init_arm(),
    f.PresetFrame: lambda s, fr: s.go_preset(fr.name),
    f.PoseGoFrame: lambda s, fr: s.go_pose(fr.name, _as(m.PoseGoRequest, fr)),
    f.HealFrame: lambda s, fr: s.heal(),
}


class WsHub:
    """Every WebSocket connection, the one state broadcaster, and their tasks."""

    def __init__(self, services: ApiServices, token: str | None, settings: WsSettings) -> None:
        self.services = services
        self.token = token
        self.settings = settings
        self.broadcaster = StateBroadcaster(services.state, settings.state_hz)
        self.connections: set[Connection] = set()
        self.replaced_closed = 0  # state frames replaced unsent, on connections now closed
        self._tasks: set[asyncio.Task[Any]] = set()
        self._broadcast_task: asyncio.Task[None] | None = None

    # -- lifecycle (aiohttp on_startup / on_shutdown) ----------------------------------

    async def start(self, app: web.Application) -> None:
        self._broadcast_task = asyncio.create_task(self.broadcaster.run(), name="ws-broadcast")

    async def stop(self, app: web.Application) -> None:
        """Close every socket (1001), then stop the tasks; bounded, whatever the clients do.

        ``lupin run`` stops the API before the daemon's safe stop, so a stalled client
        (whose close frame can never be sent) must not hold that up: after a short
        grace its connection is aborted.
        """
        if self._broadcast_task is not None:
            self._broadcast_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._broadcast_task
        closing = [
            asyncio.ensure_future(c.ws.close(code=WSCloseCode.GOING_AWAY, message=b"stopping"))
            for c in self.connections
        ]
        if closing:
            _, late = await asyncio.wait(closing, timeout=STOP_GRACE_S)
            if late:
                for conn in self.connections:
                    if isinstance(conn.transport, asyncio.WriteTransport):
                        conn.transport.abort()
            await asyncio.gather(*closing, return_exceptions=True)
        if self._tasks:
            _, pending = await asyncio.wait(self._tasks, timeout=STOP_GRACE_S)
            for task in pending:
                task.cancel()
            await asyncio.gather(*pending, return_exceptions=True)

    @property
    def replaced_total(self) -> int:
        return self.replaced_closed + sum(c.outbox.replaced for c in self.connections)

    def _spawn(self, coro: Awaitable[Any], conn: Connection | None = None) -> asyncio.Task[Any]:
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        if conn is not None:
            conn.in_flight.add(task)
            task.add_done_callback(conn.in_flight.discard)
        return task

    # -- the handler ----------------------------------------------------------------------

    async def handle(self, request: web.Request) -> web.StreamResponse:
        if is_foreign_origin(request):
            raise ApiError(403, "foreign_origin", "WebSocket from a page of another origin")
        offered, proto = subprotocol_token(request)
        offered = bearer_of(request) or offered
        authed = self.token is None
        if self.token is not None and offered is not None:
            if not token_matches(self.token, offered):
                raise unauthorized("wrong token")
            authed = True
        # Offer the client's own bearer.* string back too: a browser fails a handshake
        # whose only protocol the server does not pick, and aiohttp would log the miss.
        protocols = (PROTOCOL, proto) if proto else (PROTOCOL,)
        ws = web.WebSocketResponse(
            heartbeat=self.settings.heartbeat_s,
            max_msg_size=self.settings.max_msg_size,
            protocols=protocols,
            compress=False,  # serialise once for all clients; no per-client deflate
            writer_limit=self.settings.writer_limit,
            timeout=STOP_GRACE_S,  # wait no longer for a client's close reply
        )
        await ws.prepare(request)
        loop = asyncio.get_running_loop()
        bucket = TokenBucket(self.settings.rate_per_s, self.settings.burst, loop.time())
        conn = Connection(ws, Outbox(), bucket, request.transport)
        if not authed and not await self._authenticate(conn):
            return ws
        await ws.send_str('{"type":"hello",' + self.services.robot().model_dump_json()[1:])
        self.connections.add(conn)
        self.broadcaster.outboxes.add(conn.outbox)
        writer = self._spawn(self._write(conn))
        try:
            await self._read(conn)
        finally:
            self.broadcaster.outboxes.discard(conn.outbox)
            self.connections.discard(conn)
            self.replaced_closed += conn.outbox.replaced
            writer.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await writer
        return ws

    async def _authenticate(self, conn: Connection) -> bool:
        """The first frame must be ``{"type": "auth", "token": ...}`` with the right token."""
        assert self.token is not None
        try:
            msg = await conn.ws.receive(timeout=self.settings.auth_timeout_s)
        except TimeoutError:
            msg = None
        frame: Any = None
        if msg is not None and msg.type is WSMsgType.TEXT:
            with contextlib.suppress(ApiError):
                frame = validate_frame(f.CLIENT_FRAME, loads(msg.data))
        if isinstance(frame, f.AuthFrame) and token_matches(self.token, frame.token):
            conn.reply(frame.id, m.Ok())
            for text in conn.outbox.replies:
                await conn.ws.send_str(text)
            conn.outbox.replies.clear()
            return True
        why = "wrong token" if isinstance(frame, f.AuthFrame) else "send an auth frame first"
        with contextlib.suppress(ConnectionError):
            error = m.ErrorBody(code="unauthorized", message=why).model_dump_json()
            await conn.ws.send_str(f'{{"type":"error","error":{error}}}')
        await conn.ws.close(code=CLOSE_UNAUTHORIZED, message=b"unauthorized")
        return False

    async def _write(self, conn: Connection) -> None:
        with contextlib.suppress(ConnectionError):
            while not conn.ws.closed:
                for text in await conn.outbox.take():
                    await conn.ws.send_str(text)
                    conn.outbox.sent += 1

    async def _read(self, conn: Connection) -> None:
        loop = asyncio.get_running_loop()
        async for msg in conn.ws:
            # Backpressure: read no more from a client whose replies pile up unread.
            await conn.outbox.room.wait()
            if msg.type is WSMsgType.TEXT:
                if not conn.bucket.take(loop.time()):
                    conn.refuse(frame_id_of(_peek(msg.data)), "rate_limited", "too many messages")
                    continue
                self._on_text(conn, msg.data)
            elif msg.type is WSMsgType.BINARY:
                conn.refuse(None, "invalid_frame", "send JSON text frames")
            elif msg.type is WSMsgType.ERROR:
                log.info("WebSocket client dropped: %s", conn.ws.exception())
                break

    def _on_text(self, conn: Connection, text: str) -> None:
        data: Any = None
        try:
            data = loads(text)
            frame = validate_frame(f.CLIENT_FRAME, data)
        except ApiError as exc:
            conn.refuse(frame_id_of(data), exc.code, exc.message)
            return
        if isinstance(frame, f.AuthFrame):
            conn.reply(frame.id, m.Ok())  # already authenticated (or no token needed)
        elif isinstance(frame, f.TwistFrame):
            # Inline, not a task: the twist stream must stay in order and cheap.
            try:
                conn.reply(frame.id, self.services.submit_twist(_as(m.TwistRequest, frame)))
            except ServiceError as exc:
                conn.refuse(frame.id, exc.code, exc.message)
            except Exception:
                log.exception("unhandled error in a WebSocket twist")
                conn.refuse(frame.id, "internal", "internal error; the daemon log has the details")
        elif len(conn.in_flight) >= self.settings.max_in_flight:
            conn.refuse(frame.id, "busy", "too many commands in flight; wait for replies")
        else:
            self._spawn(self._command(conn, frame), conn)

    async def _command(self, conn: Connection, frame: BaseModel) -> None:
        frame_id = getattr(frame, "id", None)
        try:
            result = await COMMANDS[type(frame)](self.services, frame)
        except ServiceError as exc:
            conn.refuse(frame_id, exc.code, exc.message)
        except ApiError as exc:
            conn.refuse(frame_id, exc.code, exc.message)
        except Exception:
            log.exception("unhandled error in WebSocket command %s", type(frame).__name__)
            conn.refuse(frame_id, "internal", "internal error; the daemon log has the details")
        else:
            conn.reply(frame_id, result)


def _peek(text: str) -> Any:
    """Best effort parse for the id of a frame refused before validation."""
    try:
        return loads(text)
    except ApiError:
        return None
