"""A WebSocket fuzzer against ``/api/ws``: nothing crashes, every refusal is clear, nothing moves.

What the server promises (lupin/api/ws.py, lupin/api/bodies.py):

* a malformed frame (not JSON, NaN/Infinity/overflowing numbers, not an object,
  no or unknown ``type``, wrong-typed or unknown fields) is answered with an error
  frame whose code says which (``invalid_json``, ``invalid_frame``) and whose
  message names the field or the problem; when the frame carried a usable ``id``
  the refusal is a ``reply`` with that id and ``ok: false``; the socket stays open;
* a binary frame is refused (``invalid_frame``, "send JSON text frames");
* a frame over the size limit closes that socket with 1009 (message too big), text
  that is not UTF-8 with 1007, protocol garbage with 1002; only that socket;
* with a token, anything before the ``auth`` frame is refused ("send an auth frame
  first") and the socket closed with 4401;
* every command carrying an id is answered exactly once, whatever order or
  repetition the ids come in;
* other clients keep receiving state at their rate, the control tick keeps
  running, and no servo receives a single write.

Every random choice comes from one seeded generator (``$LUPIN_FUZZ_SEED``,
printed), so a failure replays.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import itertools
import json
import logging
import os
import random
import string
import time
from collections import Counter
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from typing import Any

import aiohttp
import pytest

from lupin.api import ApiServer
from lupin.api.ws import CLOSE_UNAUTHORIZED, WsSettings
from lupintest.harness import Sim, wait_for

from .helpers import TOKEN, get_json, running_api, running_daemon
from .hostile_helpers import assert_nothing_written, assert_still_ticking, fuzz_seed, rng_for

FRAMES = 1000  # malformed frames per run, one at a time, each answered before the next
# The fuzzer waits for each answer, so the token bucket (50/s) would only slow it down;
# rate limiting has its own tests (tests/api/test_ws.py).
FUZZ_WS = WsSettings(rate_per_s=10_000, burst=10_000)
MAX_MSG = FUZZ_WS.max_msg_size

# Valid frames to mutate: (frame, {field: kind}) where kind is the field's JSON type.
TEMPLATES: list[tuple[dict[str, Any], dict[str, str]]] = [
    (
        {"type": "twist", "source": "manual", "linear_x": 0.1, "linear_y": 0.0, "angular_z": 0.2},
        {"source": "str", "linear_x": "num", "linear_y": "num", "angular_z": "num"},
    ),
    ({"type": "estop", "engaged": True}, {"engaged": "bool"}),
    (
        {"type": "joint", "joint": "elbow_flex", "angle_deg": 5.0, "speed_deg_s": 20.0},
        {"joint": "str", "angle_deg": "num", "speed_deg_s": "num"},
    ),
    ({"type": "gripper", "angle_deg": 5.0}, {"angle_deg": "num"}),
    ({"type": "torque", "enabled": True}, {"enabled": "bool"}),
    ({"type": "preset", "name": "home"}, {"name": "str"}),
    (
        {"type": "pose_go", "name": "p", "max_travel_rad": 0.3, "speed_rad_s": 0.5},
        {"name": "str", "max_travel_rad": "num", "speed_rad_s": "num"},
    ),
    ({"type": "auth", "token": "x"}, {"token": "str"}),
]
WRONG: dict[str, list[Any]] = {
    "num": ["1.5", True, [], {}, "NaN"],  # not None: speed_deg_s may be null
    "bool": [1, 0, "true", None, [], 1.0],
    "str": [1, True, None, [], {}, 2.5],
}
NON_FINITE = ["NaN", "Infinity", "-Infinity", "1e400", "-1e999"]
USABLE_IDS: list[Any] = ["a", "x" * 64, 0, 7, 2**53]
UNUSABLE_IDS: list[Any] = [True, -1, 1.5, 2**60, "y" * 65, [], {}, None]


@dataclass(frozen=True)
class Bad:
    kind: str
    data: str | bytes
    codes: frozenset[str]  # acceptable error codes
    needle: str | None  # must appear in the error message
    id: Any = None  # a usable id: the refusal is a reply carrying it


def _dumps(obj: Any) -> str:
    return json.dumps(obj)


def _with_id(rng: random.Random, frame: dict[str, Any]) -> tuple[dict[str, Any], Any]:
    """Maybe attach an id: (frame, the id if the server can read it back, else None)."""
    roll = rng.random()
    if roll < 0.4:
        return frame, None
    if roll < 0.8:
        ident = rng.choice(USABLE_IDS)
        return {**frame, "id": ident}, ident
    return {**frame, "id": rng.choice(UNUSABLE_IDS)}, None


def _random_text(rng: random.Random) -> Bad:
    pool = string.printable + '{}[]":,' * 4 + "\u00e9\u2603\U0001f916"
    text = "".join(rng.choice(pool) for _ in range(rng.randint(1, 200)))
    return Bad("random text", text, frozenset({"invalid_json", "invalid_frame"}), None)


def _binary(rng: random.Random) -> Bad:
    data = rng.randbytes(rng.randint(0, 300))
    return Bad("binary frame", data, frozenset({"invalid_frame"}), "text")


def _truncated(rng: random.Random) -> Bad:
    frame, _ = rng.choice(TEMPLATES)
    text = _dumps(frame)
    return Bad(
        "truncated JSON", text[: rng.randint(1, len(text) - 1)], frozenset({"invalid_json"}), None
    )


def _non_finite(rng: random.Random) -> Bad:
    frame, fields = rng.choice([t for t in TEMPLATES if "num" in t[1].values()])
    field = rng.choice([f for f, k in fields.items() if k == "num"])
    literal = rng.choice(NON_FINITE)
    text = _dumps({**frame, field: "@@"}).replace('"@@"', literal)
    return Bad(f"{literal} in {field}", text, frozenset({"invalid_json"}), "finite")


def _huge(rng: random.Random) -> Bad:
    frame, fields = rng.choice(TEMPLATES[:1])  # twist: every number has a range
    field = rng.choice([f for f, k in fields.items() if k == "num"])
    value = rng.choice([1e308, -1e308, 10**30, 2.5e3, -7])
    framed, ident = _with_id(rng, {**frame, field: value})
    return Bad(f"huge {field}", _dumps(framed), frozenset({"invalid_frame"}), field, ident)


def _too_many_digits(rng: random.Random) -> Bad:
    text = _dumps({"type": "twist", "source": "manual", "linear_x": "@@"})
    digits = "9" * rng.randint(4400, 9000)
    return Bad(
        "a 5000-digit number", text.replace('"@@"', digits), frozenset({"invalid_json"}), None
    )


def _wrong_type(rng: random.Random) -> Bad:
    frame, fields = rng.choice(TEMPLATES)
    field, kind = rng.choice(sorted(fields.items()))
    framed, ident = _with_id(rng, {**frame, field: rng.choice(WRONG[kind])})
    return Bad(f"wrong type in {field}", _dumps(framed), frozenset({"invalid_frame"}), field, ident)


def _unknown_type(rng: random.Random) -> Bad:
    word = "".join(rng.choice(string.ascii_lowercase) for _ in range(rng.randint(3, 12)))
    framed, ident = _with_id(rng, {"type": word, "linear_x": 1})
    return Bad("unknown type", _dumps(framed), frozenset({"invalid_frame"}), word, ident)


def _no_type(rng: random.Random) -> Bad:
    frame, _ = rng.choice(TEMPLATES)
    framed, ident = _with_id(rng, {k: v for k, v in frame.items() if k != "type"})
    return Bad("no type", _dumps(framed), frozenset({"invalid_frame"}), "type", ident)


def _unknown_field(rng: random.Random) -> Bad:
    frame, _ = rng.choice(TEMPLATES)
    field = "zz_" + "".join(rng.choice(string.ascii_lowercase) for _ in range(6))
    framed, ident = _with_id(rng, {**frame, field: 1})
    return Bad("unknown field", _dumps(framed), frozenset({"invalid_frame"}), field, ident)


def _not_an_object(rng: random.Random) -> Bad:
    value = rng.choice(["[]", "[1, 2]", "5", '"twist"', "null", "true", "-0.5"])
    return Bad("not an object", value, frozenset({"invalid_frame"}), "JSON object")


def _deep(rng: random.Random) -> Bad:
    opener, closer = rng.choice([("[", "]"), ('{"a":', "}")])
    depth = rng.randint(2_000, (MAX_MSG - 10) // (len(opener) + len(closer)))
    return Bad("deep nesting", opener * depth + closer * depth, frozenset({"invalid_json"}), None)


GENERATORS: list[Callable[[random.Random], Bad]] = [
    _random_text,
    _binary,
    _truncated,
    _non_finite,
    _huge,
    _too_many_digits,
    _wrong_type,
    _unknown_type,
    _no_type,
    _unknown_field,
    _not_an_object,
    _deep,
]


# -- clients ------------------------------------------------------------------------------


async def next_not_state(ws: aiohttp.ClientWebSocketResponse, timeout: float = 3.0) -> Any:
    async with asyncio.timeout(timeout):
        while True:
            msg = await ws.receive()
            assert msg.type is aiohttp.WSMsgType.TEXT, (msg.type, msg.data, msg.extra)
            frame = json.loads(msg.data)
            if frame["type"] != "state":
                return frame


async def close_code(ws: aiohttp.ClientWebSocketResponse, timeout: float = 3.0) -> int | None:
    """Read to the close frame; its code (None if the connection just ended)."""
    async with asyncio.timeout(timeout):
        while True:
            msg = await ws.receive()
            if msg.type is aiohttp.WSMsgType.CLOSE:
                return int(msg.data)
            if msg.type in (aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.ERROR):
                return ws.close_code


@dataclass
class Observer:
    """A well-behaved client: the times at which it received state frames."""

    states: list[float]
    task: asyncio.Task[None]

    def max_gap(self, t0: float, t1: float) -> float:
        stamps = [t0, *(t for t in self.states if t0 <= t <= t1), t1]
        return max(b - a for a, b in itertools.pairwise(stamps))


@contextlib.asynccontextmanager
async def observer(http: aiohttp.ClientSession, api: ApiServer) -> AsyncIterator[Observer]:
    ws = await http.ws_connect(api.url + "/api/ws")
    assert (await ws.receive_json(timeout=2))["type"] == "hello"
    states: list[float] = []

    async def read() -> None:
        async for msg in ws:
            if json.loads(msg.data)["type"] == "state":
                states.append(time.monotonic())

    obs = Observer(states, asyncio.create_task(read(), name="ws-observer"))
    try:
        yield obs
    finally:
        await ws.close()
        await obs.task


def no_errors_logged(caplog: pytest.LogCaptureFixture) -> None:
    bad = [
        f"{r.name}: {r.getMessage()}"
        for r in caplog.records
        if r.levelno >= logging.ERROR or "Traceback" in r.getMessage()
    ]
    assert not bad, f"hostile frames reached an unhandled error: {bad}"


# -- the tests -----------------------------------------------------------------------------


async def check_refusal(ws: aiohttp.ClientWebSocketResponse, bad: Bad) -> None:
    if isinstance(bad.data, bytes):
        await ws.send_bytes(bad.data)
    else:
        await ws.send_str(bad.data)
    frame = await next_not_state(ws)
    where = f"{bad.kind}: {str(bad.data)[:120]!r} -> {frame}"
    if bad.id is not None:
        assert frame["type"] == "reply" and frame["id"] == bad.id, where
        assert frame["ok"] is False, where
    else:
        assert frame["type"] == "error", where
    error = frame["error"]
    assert error["code"] in bad.codes, where
    assert error["message"], where
    if bad.needle is not None:
        assert bad.needle in error["message"], where


async def test_malformed_frames_are_refused_by_name_and_nothing_moves(
    sim: Sim, http: aiohttp.ClientSession, caplog: pytest.LogCaptureFixture
) -> None:
    rng = rng_for(fuzz_seed("ws fuzz"), "frames")
    caplog.set_level(logging.INFO)
    async with running_daemon(sim) as daemon, running_api(daemon, ws=FUZZ_WS) as api:
        before = await get_json(http, api.url + "/api/state")
        async with observer(http, api) as obs:
            t0 = time.monotonic()
            kinds: Counter[str] = Counter()
            async with http.ws_connect(api.url + "/api/ws") as ws:
                assert (await ws.receive_json(timeout=2))["type"] == "hello"
                for _ in range(FRAMES):
                    bad = rng.choice(GENERATORS)(rng)
                    kinds[bad.kind.split(" in ")[0]] += 1
                    await check_refusal(ws, bad)
                # Still the same socket, still serving: a good command is answered.
                await ws.send_json({"type": "twist", "source": "manual", "id": "alive"})
                assert (await next_not_state(ws))["ok"] is True
            t1 = time.monotonic()
            # The well-behaved client was fed at its rate all along (20 Hz: 50 ms).
            assert obs.max_gap(t0, t1) < 0.5, obs.max_gap(t0, t1)
        print(sorted(kinds.items()))
        # Nothing moved before the one good twist at the very end.
        assert_nothing_written(sim, t0, "malformed WebSocket frames")
        after = await get_json(http, api.url + "/api/state")
        assert after["estop"] is before["estop"] is False
        assert [j["torque"] for j in after["joints"]] == [j["torque"] for j in before["joints"]]
        await assert_still_ticking(sim, daemon)
    no_errors_logged(caplog)


async def test_oversized_non_utf8_and_protocol_garbage_close_only_that_socket(
    sim: Sim, http: aiohttp.ClientSession, caplog: pytest.LogCaptureFixture
) -> None:
    rng = rng_for(fuzz_seed("ws close"), "close")
    caplog.set_level(logging.INFO)
    async with running_daemon(sim) as daemon, running_api(daemon, ws=FUZZ_WS) as api:
        async with observer(http, api) as obs:
            t0 = time.monotonic()
            oversized: list[tuple[str, bytes | str]] = [
                ("text", _dumps({"type": "twist", "source": "manual", "pad": "x" * MAX_MSG})),
                ("text", "[" * (MAX_MSG + 1)),
                ("binary", rng.randbytes(MAX_MSG + rng.randint(1, 50_000))),
            ]
            for how, data in oversized:
                async with http.ws_connect(api.url + "/api/ws") as ws:
                    await ws.receive_json(timeout=2)
                    if isinstance(data, bytes):
                        await ws.send_bytes(data)
                    else:
                        await ws.send_str(data)
                    code = await close_code(ws)
                    assert code == aiohttp.WSCloseCode.MESSAGE_TOO_BIG, (how, code)
            # Text that is not UTF-8: the frame itself is invalid.
            async with http.ws_connect(api.url + "/api/ws") as ws:
                await ws.receive_json(timeout=2)
                await ws.send_frame(b'{"type": "\xff\xfe"}', aiohttp.WSMsgType.TEXT)
                assert await close_code(ws) == aiohttp.WSCloseCode.INVALID_TEXT
            # Frames that break the protocol itself, after a real upgrade: closed with a
            # protocol error (1002), bad text (1007) or too big (1009), never a crash.
            for name, garbage in protocol_garbage(rng):
                code = await raw_garbage(api, garbage)
                assert code in (1002, 1007, 1009), (name, garbage[:16].hex(), code)
            await wait_for(lambda: len(api.hub.connections) == 1, 3.0)  # only the observer
            t1 = time.monotonic()
            assert obs.max_gap(t0, t1) < 0.5, obs.max_gap(t0, t1)
        assert_nothing_written(sim, t0, "oversized and garbage WebSocket frames")
        await assert_still_ticking(sim, daemon)
    no_errors_logged(caplog)


async def raw_upgrade(api: ApiServer) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    """A WebSocket upgrade by hand; returns the stream once the 101 is read."""
    host, port = api.url.removeprefix("http://").rsplit(":", 1)
    reader, writer = await asyncio.open_connection(host, int(port))
    key = base64.b64encode(os.urandom(16)).decode()
    writer.write(
        (
            f"GET /api/ws HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
            f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
            "Sec-WebSocket-Version: 13\r\n\r\n"
        ).encode()
    )
    await writer.drain()
    head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 2.0)
    assert head.startswith(b"HTTP/1.1 101"), head
    return reader, writer


def ws_frame(
    opcode: int, payload: bytes, *, fin: bool = True, rsv: int = 0, masked: bool = True
) -> bytes:
    """One client frame as the RFC 6455 wire has it (masked, as a client must)."""
    head = bytes([(0x80 if fin else 0) | (rsv << 4) | opcode])
    n = len(payload)
    mask_bit = 0x80 if masked else 0
    if n < 126:
        head += bytes([mask_bit | n])
    elif n < 1 << 16:
        head += bytes([mask_bit | 126]) + n.to_bytes(2, "big")
    else:
        head += bytes([mask_bit | 127]) + n.to_bytes(8, "big")
    if not masked:
        return head + payload
    key = os.urandom(4)
    return head + key + bytes(b ^ key[i % 4] for i, b in enumerate(payload))


def protocol_garbage(rng: random.Random) -> list[tuple[str, bytes]]:
    noise = rng.randbytes(rng.randint(8, 64))
    return [
        ("reserved opcode", ws_frame(rng.choice([3, 4, 5, 6, 7, 11, 12, 15]), noise)),
        ("reserved bits", ws_frame(1, b"{}", rsv=rng.randint(1, 7))),
        ("continuation without a start", ws_frame(0, b'"x"}')),
        ("control frame too long", ws_frame(9, rng.randbytes(rng.randint(126, 1000)))),
        ("fragmented ping", ws_frame(9, b"p", fin=False)),
        ("close code 999", ws_frame(8, (999).to_bytes(2, "big"))),
        ("one-byte close", ws_frame(8, b"\x03")),
        ("bad UTF-8 text", ws_frame(1, b'{"type": "\xc3\x28"}')),
        ("declared 2^63 bytes", bytes([0x82, 0xFF]) + (2**63 - 1).to_bytes(8, "big")),
        # Random bytes, then enough more that any length they declare is complete.
        ("noise", noise + rng.randbytes(MAX_MSG + 1024)),
    ]


TIMED_OUT = -1


async def raw_garbage(api: ApiServer, garbage: bytes) -> int | None:
    """Send ``garbage`` on a raw upgraded connection; the close code the server sent
    (None: it hung up without one; TIMED_OUT: it kept the connection open)."""
    reader, writer = await raw_upgrade(api)
    try:
        with contextlib.suppress(ConnectionError):
            writer.write(garbage)
            await writer.drain()
        async with asyncio.timeout(3.0):
            while True:
                head = await reader.readexactly(2)
                length = head[1] & 0x7F
                if length == 126:
                    length = int.from_bytes(await reader.readexactly(2), "big")
                elif length == 127:
                    length = int.from_bytes(await reader.readexactly(8), "big")
                payload = await reader.readexactly(length)
                if head[0] & 0x0F == 0x8:  # the server's close frame
                    return int.from_bytes(payload[:2], "big") if len(payload) >= 2 else None
    except (ConnectionError, asyncio.IncompleteReadError):
        return None  # hung up without a close frame
    except TimeoutError:
        return TIMED_OUT
    finally:
        writer.close()
        with contextlib.suppress(ConnectionError):
            await writer.wait_closed()


async def test_rapid_open_close_and_half_open_upgrades(
    sim: Sim, http: aiohttp.ClientSession, caplog: pytest.LogCaptureFixture
) -> None:
    rng = rng_for(fuzz_seed("ws churn"), "churn")
    caplog.set_level(logging.INFO)
    async with running_daemon(sim) as daemon, running_api(daemon, ws=FUZZ_WS) as api:
        async with observer(http, api) as obs:
            t0 = time.monotonic()

            async def churn(i: int) -> None:
                how = rng.choice(["close", "close-after-hello", "abort", "upgrade-then-drop"])
                if how.startswith("close"):
                    ws = await http.ws_connect(api.url + "/api/ws")
                    if how == "close-after-hello":
                        await ws.receive_json(timeout=2)
                        await ws.send_str("{not json")
                    await ws.close()
                elif how == "abort":  # the TCP connection vanishes mid-handshake
                    host, port = api.url.removeprefix("http://").rsplit(":", 1)
                    _, writer = await asyncio.open_connection(host, int(port))
                    writer.write(b"GET /api/ws HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\n")
                    writer.transport.abort()
                else:  # upgraded, then the client vanishes without a close frame
                    _, writer = await raw_upgrade(api)
                    writer.transport.abort()

            for batch in range(6):
                await asyncio.gather(*(churn(batch * 10 + i) for i in range(10)))
            await wait_for(lambda: len(api.hub.connections) == 1, 3.0)  # only the observer
            t1 = time.monotonic()
            assert obs.max_gap(t0, t1) < 0.5, obs.max_gap(t0, t1)
        assert_nothing_written(sim, t0, "WebSocket churn")
        await assert_still_ticking(sim, daemon)
    no_errors_logged(caplog)


async def test_ids_repeated_and_out_of_order_are_each_answered_once(
    sim: Sim, http: aiohttp.ClientSession
) -> None:
    """Commands refused by the robot's state (torque off): each frame one reply, by its id."""
    rng = rng_for(fuzz_seed("ws ids"), "ids")
    async with running_daemon(sim) as daemon, running_api(daemon, ws=FUZZ_WS) as api:
        t0 = time.monotonic()
        async with http.ws_connect(api.url + "/api/ws") as ws:
            await ws.receive_json(timeout=2)
            pool: list[Any] = [3, 1, 2, 2, "b", "a", "b", 0, 2**53, 1]
            ids = [rng.choice(pool) for _ in range(40)]
            for ident in ids:  # sent back to back: up to max_in_flight run concurrently
                joint = rng.choice(["elbow_flex", "wrist_flex", "gripper", "knee"])
                frame = {"type": "joint", "id": ident, "joint": joint, "angle_deg": 30.0}
                if joint == "gripper":
                    frame = {"type": "gripper", "id": ident, "angle_deg": 30.0}
                await ws.send_json(frame)
            replies = [await next_not_state(ws) for _ in ids]
        got = Counter(json.dumps(r["id"]) for r in replies)
        assert got == Counter(json.dumps(i) for i in ids)
        for r in replies:
            assert r["type"] == "reply" and r["ok"] is False, r
            code = r["error"]["code"]
            assert code in ("torque_off", "unknown_joint", "busy"), r
            assert r["error"]["message"], r
        assert_nothing_written(sim, t0, "refused commands")
        await assert_still_ticking(sim, daemon)


async def test_with_a_token_nothing_before_auth_is_obeyed(
    sim: Sim, http: aiohttp.ClientSession
) -> None:
    """Out of order: a twist (or garbage) before the auth frame is refused, the socket closed."""
    rng = rng_for(fuzz_seed("ws auth"), "auth")
    async with running_daemon(sim) as daemon, running_api(daemon, token=TOKEN) as api:
        t0 = time.monotonic()
        firsts: list[tuple[str | bytes, str]] = [
            (_dumps({"type": "twist", "source": "manual", "linear_x": 1.0}), "auth frame first"),
            (_dumps({"type": "estop", "id": 1, "engaged": False}), "auth frame first"),
            (_dumps({"type": "auth", "token": TOKEN[:-1] + "0"}), "wrong token"),
            (_dumps({"type": "auth", "token": 12345}), "auth frame first"),
            (_dumps({"type": "auth", "token": TOKEN, "extra": 1}), "auth frame first"),
            ('{"type": "auth", "token": NaN}', "auth frame first"),
            (rng.randbytes(32), "auth frame first"),
            (_random_text(rng).data, "auth frame first"),
        ]
        for first, needle in firsts:
            async with http.ws_connect(api.url + "/api/ws") as ws:
                if isinstance(first, bytes):
                    await ws.send_bytes(first)
                else:
                    await ws.send_str(first)
                frame = await ws.receive_json(timeout=3)
                assert frame["type"] == "error" and frame["error"]["code"] == "unauthorized"
                assert needle in frame["error"]["message"], (first, frame)
                # Whatever follows is never read: the socket is closed.
                with contextlib.suppress(ConnectionError):
                    await ws.send_json({"type": "twist", "source": "manual", "linear_x": 1.0})
                assert await close_code(ws) == CLOSE_UNAUTHORIZED
        # The right token still works.
        async with http.ws_connect(api.url + "/api/ws") as ws:
            await ws.send_json({"type": "auth", "id": "a", "token": TOKEN})
            assert (await ws.receive_json(timeout=3)) == {
                "type": "reply",
                "id": "a",
                "ok": True,
                "result": {"ok": True},
            }
            assert (await ws.receive_json(timeout=3))["type"] == "hello"
        assert_nothing_written(sim, t0, "frames before auth")
        assert daemon.mux.status(daemon.clock()).active is None
        await assert_still_ticking(sim, daemon)
