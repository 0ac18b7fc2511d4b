"""Security, exhaustively: who may command the robot, what never reaches a log, who is throttled.

``tests/api/test_security.py`` samples the policy (one request per route, one
frame). Here every case is derived from the *live* daemon, so an endpoint or a
WebSocket command added later is covered without editing this file:

* every mutating operation (POST, PUT, PATCH, DELETE) in the daemon's own
  ``/api/openapi.json``, cross-checked against the routes the server really has,
  and every client command frame the document lists for ``/api/ws``, is refused
  401 without the token and with every wrong way of offering it, and changes
  nothing: no packet written to any servo, state, poses and heal unchanged;
* a foreign ``Origin`` is refused 403 on each of them, even with the right token,
  and on the WebSocket upgrade;
* the token never appears in any log output, nor in any answer, whether it was
  sent in a header, the query, a subprotocol, a first frame or a malformed
  request: captured at DEBUG in-process (aiohttp's access log included) and from
  a ``lupin run`` process's stdout and stderr;
* WebSocket clients over their message budget are answered ``rate_limited``
  and HTTP floods are served, and neither slows the control tick (judged from
  ``/metrics`` of a daemon in its own process, on a simulator in its own process).
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import logging
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from lupin.api import ApiServer
from lupin.api.ws import CLOSE_UNAUTHORIZED
from lupin.daemon import Daemon
from lupintest.harness import Sim

from .helpers import (
    TOKEN,
    MergedDaemonProcess,
    SimProcess,
    get_json,
    periods_within,
    running_api,
    running_daemon,
    scrape,
    tick_rate,
)

WRONG = "tok-rel-wrong-5e9b7c3a1d2f4e6a8b0c"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
POSE = "rel_pose"
MUTATING = ("post", "put", "patch", "delete")
# Statuses that would mean a generated request never reached its handler's own logic.
NOT_PAST_THE_DOOR = {400, 401, 403, 404, 405, 413, 415}
FOREIGN_ORIGINS = (
    "http://evil.example",
    "null",
    "file://",
    "http://localhost:{port}",  # the same machine by another name is another origin
    "http://127.0.0.1:1",  # another port
    "https://evil.example:{port}",
)


# -- the operations, from the live OpenAPI document ---------------------------------------


@dataclass(frozen=True)
class Op:
    method: str  # upper case
    template: str  # the path as documented
    path: str  # with parameters filled in
    body: dict[str, Any] | None

    def __str__(self) -> str:
        return f"{self.method} {self.path}"


def _deref(schema: dict[str, Any], doc: dict[str, Any]) -> dict[str, Any]:
    while "$ref" in schema:
        node: Any = doc
        for part in schema["$ref"].removeprefix("#/").split("/"):
            node = node[part]
        schema = node
    return schema


def _branch(schema: dict[str, Any], doc: dict[str, Any]) -> dict[str, Any]:
    """The first non-null branch of an anyOf/oneOf (or the schema itself)."""
    schema = _deref(schema, doc)
    for key in ("anyOf", "oneOf"):
        if key in schema:
            options = [_deref(s, doc) for s in schema[key]]
            return _branch(next(s for s in options if s.get("type") != "null"), doc)
    return schema


def example(schema: dict[str, Any], doc: dict[str, Any], fill: dict[str, Any]) -> Any:
    """A valid instance that *does something*: required fields, plus every optional
    number and boolean (a twist that moves, a flag that is set); ``fill`` by field name."""
    schema = _branch(schema, doc)
    if "const" in schema:
        return schema["const"]
    if "enum" in schema:
        return schema["enum"][0]
    kind = schema.get("type")
    if kind == "object":
        out: dict[str, Any] = {}
        required = set(schema.get("required", []))
        for name, prop in schema.get("properties", {}).items():
            if name in fill:
                out[name] = fill[name]
            elif name in required or _branch(prop, doc).get("type") in (
                "number",
                "integer",
                "boolean",
            ):
                out[name] = example(prop, doc, fill)
        return out
    if kind == "boolean":
        return True
    if kind in ("number", "integer"):
        hi = schema.get("maximum", schema.get("exclusiveMaximum"))
        value = 0.1 * hi if hi is not None else 10.0  # inside any window, and not zero
        return int(value) if kind == "integer" else value
    if kind == "string":
        return "x" * max(1, schema.get("minLength", 1))
    if kind == "array":
        return []
    raise AssertionError(f"no example for schema {schema}")


def _param_value(param: dict[str, Any]) -> str:
    schema = param["schema"]
    if "enum" in schema:
        return str(schema["enum"][0])
    assert param["name"] == "pose", f"a path parameter this test does not know: {param}"
    return POSE


def mutating_ops(doc: dict[str, Any]) -> list[Op]:
    ops = []
    for template, item in doc["paths"].items():
        for method, op in item.items():
            if method not in MUTATING:
                continue
            assert op.get("security") == [{"bearerAuth": []}], f"{method} {template} is open"
            path = template
            for param in op.get("parameters", []):
                if param["in"] == "path":
                    path = path.replace("{" + param["name"] + "}", _param_value(param))
            body = None
            if "requestBody" in op:
                schema = op["requestBody"]["content"]["application/json"]["schema"]
                body = example(schema, doc, {})
            ops.append(Op(method.upper(), template, path, body))
    return ops


def client_frames(doc: dict[str, Any]) -> list[dict[str, Any]]:
    """One valid frame per WebSocket command the document lists (auth aside)."""
    ws = doc["paths"]["/api/ws"]["get"]
    assert ws.get("security") == [{"bearerAuth": []}]
    joint = doc["paths"]["/api/arm/joints/{joint}"]["post"]["parameters"][0]["schema"]["enum"][0]
    preset = doc["paths"]["/api/arm/presets/{preset}"]["post"]["parameters"][0]["schema"]["enum"]
    frames = []
    for n, ref in enumerate(ws["x-lupin-frames"]["client"]):
        schema = _deref({"$ref": ref}, doc)
        kind = schema["properties"]["type"]["const"]
        if kind == "auth":
            continue
        name = preset[0] if kind == "preset" else POSE
        frames.append(example(schema, doc, {"id": f"f{n}", "joint": joint, "name": name}))
    return frames


def router_ops(api: ApiServer) -> set[tuple[str, str]]:
    """(METHOD, path template) of every mutating route the server really registered."""
    out = set()
    for route in api.app.router.routes():
        if route.method.lower() in MUTATING:
            info = route.resource.get_info() if route.resource is not None else {}
            out.add((route.method, str(info.get("formatter") or info.get("path"))))
    return out


async def request(
    http: aiohttp.ClientSession,
    base: str,
    op: Op,
    headers: dict[str, str] | None = None,
    query: str = "",
) -> tuple[int, dict[str, str], str]:
    kwargs: dict[str, Any] = {} if op.body is None else {"json": op.body}
    url = base + op.path + query
    async with http.request(op.method, url, headers=headers or {}, **kwargs) as resp:
        return resp.status, dict(resp.headers), await resp.text()


# -- what "nothing changed" means ------------------------------------------------------------


async def snapshot(http: aiohttp.ClientSession, url: str, daemon: Daemon) -> dict[str, Any]:
    state = await get_json(http, url + "/api/state")
    poses = await get_json(http, url + "/api/arm/poses")
    return {
        "estop": state["estop"],
        "torque": state["torque"],
        "mux": state["mux"]["active"],
        "fresh": {k: v["fresh"] for k, v in state["mux"]["sources"].items()},
        "base": state["base"]["twist"],
        "joints": [
            (j["name"], j["commanded_deg"], j["target_deg"], j["torque"]) for j in state["joints"]
        ],
        "poses": sorted(p["name"] for p in poses["poses"]),
        "heal": id(daemon.last_heal),
        "restarts": list(daemon.restarts),
    }


@pytest.fixture()
async def secured(sim: Sim) -> AsyncIterator[tuple[Daemon, ApiServer]]:
    """The daemon with a token, torque on and a taught pose: any accepted command would act."""
    async with running_daemon(sim) as daemon, running_api(daemon, token=TOKEN) as api:
        async with aiohttp.ClientSession(headers=AUTH) as admin:
            async with admin.post(api.url + "/api/arm/torque", json={"enabled": True}) as resp:
                assert (resp.status, await resp.json()) == (200, {"torque": "on"})
            async with admin.put(api.url + f"/api/arm/poses/{POSE}") as resp:
                assert resp.status == 200, await resp.text()
        await asyncio.sleep(0.2)  # let the energised arm settle
        yield daemon, api


async def live_document(http: aiohttp.ClientSession, api: ApiServer) -> dict[str, Any]:
    doc: dict[str, Any] = await get_json(http, api.url + "/api/openapi.json")
    return doc


# -- 401: every mutating operation, every wrong way of offering the token -----------------


def wrong_credentials() -> dict[str, tuple[dict[str, str], str]]:
    """name -> (headers, query): each must be refused."""
    basic = base64.b64encode(f"lupin:{TOKEN}".encode()).decode()
    return {
        "none": ({}, ""),
        "wrong": ({"Authorization": f"Bearer {WRONG}"}, ""),
        "longer": ({"Authorization": f"Bearer {TOKEN}x"}, ""),
        "prefix": ({"Authorization": f"Bearer {TOKEN[:-1]}"}, ""),
        "empty": ({"Authorization": "Bearer "}, ""),
        "no_scheme": ({"Authorization": TOKEN}, ""),
        "basic": ({"Authorization": f"Basic {basic}"}, ""),
        "query": ({}, f"?token={TOKEN}&access_token={TOKEN}"),
        "cookie": ({"Cookie": f"token={TOKEN}"}, ""),
        "api_key": ({"X-Api-Key": TOKEN, "X-Auth-Token": TOKEN}, ""),
        # The WebSocket's browser credential must not open the HTTP door.
        "subprotocol": ({"Sec-WebSocket-Protocol": f"bearer.{TOKEN}"}, ""),
    }


async def test_every_documented_mutation_needs_the_token_and_changes_nothing(
    sim: Sim, http: aiohttp.ClientSession, secured: tuple[Daemon, ApiServer]
) -> None:
    daemon, api = secured
    doc = await live_document(http, api)
    ops = mutating_ops(doc)
    # The document is the whole truth: the server has no mutating route it does not describe.
    assert {(op.method, op.template) for op in ops} == router_ops(api)
    assert len(ops) >= 11 and {op.method for op in ops} >= {"POST", "PUT", "DELETE"}

    before = await snapshot(http, api.url, daemon)
    t0 = time.monotonic()
    refused = 0
    for op in ops:
        for name, (headers, query) in wrong_credentials().items():
            status, resp_headers, text = await request(http, api.url, op, headers, query)
            assert status == 401, (str(op), name, status, text)
            assert resp_headers["WWW-Authenticate"].startswith("Bearer")
            assert json.loads(text)["error"]["code"] == "unauthorized", text
            assert TOKEN not in text and WRONG not in text
            refused += 1
    # Methods a path does not have are refused too (405), and change nothing either.
    for template in doc["paths"]:
        path = next((op.path for op in ops if op.template == template), None)
        if path is None:
            continue
        for method in MUTATING:
            if method in doc["paths"][template]:
                continue
            async with http.request(method.upper(), api.url + path) as resp:
                assert resp.status in (401, 405), (method, path, resp.status)
    assert sim.all_writes(since=t0) == [], "a refused request reached a servo"
    assert await snapshot(http, api.url, daemon) == before
    assert refused == len(ops) * len(wrong_credentials())

    # Not vacuous: with the token, the very same requests get past the door.
    order = sorted(ops, key=lambda op: (op.method == "DELETE", op.path == "/api/estop"))
    for op in order:
        status, _, text = await request(http, api.url, op, AUTH)
        assert status not in NOT_PAST_THE_DOOR, (str(op), status, text)


async def test_every_websocket_command_needs_the_token_and_changes_nothing(
    sim: Sim, http: aiohttp.ClientSession, secured: tuple[Daemon, ApiServer]
) -> None:
    daemon, api = secured
    doc = await live_document(http, api)
    frames = client_frames(doc)
    assert {f["type"] for f in frames} >= {"twist", "estop", "joint", "torque", "heal"}
    ws_url = api.url + "/api/ws"
    before = await snapshot(http, api.url, daemon)
    t0 = time.monotonic()

    # Refused at the upgrade: a wrong token in the header or as the subprotocol.
    for kwargs in (
        {"headers": {"Authorization": f"Bearer {WRONG}"}},
        {"headers": {"Authorization": f"Bearer {TOKEN}x"}},
        {"protocols": ("lupin.v1", f"bearer.{WRONG}")},
        {"protocols": (f"bearer.{TOKEN[:-1]}",)},
    ):
        with pytest.raises(aiohttp.WSServerHandshakeError) as err:
            await http.ws_connect(ws_url, **kwargs)  # type: ignore[arg-type]
        assert err.value.status == 401, kwargs

    # Upgraded without a credential: each command, sent first (or after a wrong auth
    # frame, pipelined), is answered unauthorized, the socket closed, nothing sent back.
    async def refused(first: list[dict[str, Any]], query: str = "", **kw: Any) -> None:
        async with http.ws_connect(ws_url + query, **kw) as ws:
            for frame in first:
                await ws.send_str(json.dumps(frame))
            got = await ws.receive(timeout=3)
            assert got.type is aiohttp.WSMsgType.TEXT, got
            reply = json.loads(got.data)
            assert reply["type"] == "error" and reply["error"]["code"] == "unauthorized", reply
            closing = await ws.receive(timeout=3)
            assert closing.type is aiohttp.WSMsgType.CLOSE and closing.data == CLOSE_UNAUTHORIZED
            assert TOKEN not in got.data and WRONG not in got.data

    for frame in frames:
        await refused([frame])
        await refused([{"type": "auth", "token": WRONG, "id": "a"}, frame])
        await refused([{"type": "auth", "token": TOKEN[:-1]}, frame])
        await refused([frame], query=f"?token={TOKEN}")
        await refused([frame], headers={"Cookie": f"token={TOKEN}", "X-Api-Key": TOKEN})
        await refused([{**frame, "token": TOKEN}])  # a token inside a command is not auth
    assert sim.all_writes(since=t0) == [], "a refused frame reached a servo"
    assert await snapshot(http, api.url, daemon) == before

    # Not vacuous: with the token every generated frame is a valid command.
    async with http.ws_connect(ws_url, protocols=("lupin.v1", f"bearer.{TOKEN}")) as ws:
        assert (await ws.receive_json(timeout=3))["type"] == "hello"
        pending = {f["id"] for f in frames}
        for frame in frames:
            await ws.send_str(json.dumps(frame))
        async with asyncio.timeout(10):
            while pending:
                msg = await ws.receive_json()
                if msg["type"] != "reply":
                    assert msg["type"] == "state", msg
                    continue
                pending.discard(msg["id"])
                if not msg["ok"]:
                    assert msg["error"]["code"] not in ("unauthorized", "invalid_frame"), msg


# -- 403: a foreign Origin, with or without the token ---------------------------------------


async def test_foreign_origin_is_refused_on_every_mutation_and_the_upgrade(
    sim: Sim, http: aiohttp.ClientSession, secured: tuple[Daemon, ApiServer]
) -> None:
    daemon, api = secured
    ops = mutating_ops(await live_document(http, api))
    port = api.url.rsplit(":", 1)[1]
    origins = [o.format(port=port) for o in FOREIGN_ORIGINS]
    before = await snapshot(http, api.url, daemon)
    t0 = time.monotonic()
    for op in ops:
        for origin in origins:
            for creds in ({}, AUTH):
                status, _, text = await request(http, api.url, op, {"Origin": origin, **creds})
                assert status == 403, (str(op), origin, creds, status, text)
                assert json.loads(text)["error"]["code"] == "foreign_origin"
    for origin in origins:
        for kwargs in (
            {"headers": {"Origin": origin, **AUTH}},
            {"headers": {"Origin": origin}, "protocols": ("lupin.v1", f"bearer.{TOKEN}")},
            {"headers": {"Origin": origin}},
        ):
            with pytest.raises(aiohttp.WSServerHandshakeError) as err:
                await http.ws_connect(api.url + "/api/ws", **kwargs)  # type: ignore[arg-type]
            assert err.value.status == 403, (origin, kwargs)
    assert sim.all_writes(since=t0) == []
    assert await snapshot(http, api.url, daemon) == before
    # The daemon's own page is same-origin: the HMI keeps working.
    same = {"Origin": api.url, **AUTH}
    async with http.post(api.url + "/api/estop", json={"engaged": False}, headers=same) as resp:
        assert resp.status == 200


# -- the token is never logged --------------------------------------------------------------


async def offer_the_token_every_way(http: aiohttp.ClientSession, url: str) -> list[str]:
    """Send the token (and a wrong one) every way a client might; return every answer body."""
    answers: list[str] = []
    ws_url = url + "/api/ws"

    async def http_call(method: str, path: str, **kw: Any) -> None:
        async with http.request(method, url + path, **kw) as resp:
            answers.append(await resp.text())
            answers.append(json.dumps(dict(resp.headers)))

    async def ws_call(query: str = "", first: str | None = None, **kw: Any) -> None:
        try:
            async with http.ws_connect(ws_url + query, **kw) as ws:
                if first is not None:
                    await ws.send_str(first)
                with contextlib.suppress(TimeoutError):
                    for _ in range(2):
                        msg = await ws.receive(timeout=1)
                        answers.append(str(msg.data))
                        if msg.type is not aiohttp.WSMsgType.TEXT:
                            break
        except aiohttp.WSServerHandshakeError as exc:
            answers.append(str(exc))

    for token in (TOKEN, WRONG):
        bearer = {"Authorization": f"Bearer {token}"}
        await http_call("POST", "/api/estop", json={"engaged": False}, headers=bearer)
        await http_call("POST", "/api/estop", json={"engaged": token}, headers=bearer)
        await http_call("POST", "/api/estop", data=f'{{"engaged": {token}', headers=bearer)
        await http_call("POST", "/api/nope", json={"x": 1}, headers=bearer)
        await http_call("PATCH", "/api/estop", headers=bearer)
        await http_call("POST", f"/api/estop?token={token}", json={"engaged": False})
        await http_call("GET", f"/api/state?access_token={token}", headers={"Referer": token})
        await http_call("PUT", f"/api/arm/poses/p?t={token}", headers=bearer)
        await http_call("POST", "/api/estop", json={"engaged": False}, headers={"Cookie": token})
        for protocols in ((f"bearer.{token}",), ("lupin.v1", f"bearer.{token}")):
            await ws_call(protocols=protocols)
        await ws_call(headers=bearer)
        await ws_call(query=f"?token={token}", first=json.dumps({"type": "auth"}))
        await ws_call(first=json.dumps({"type": "auth", "token": token, "id": "a"}))
        await ws_call(first=json.dumps({"type": "auth", "token": token, "extra": token}))
        await ws_call(first=f'{{"type": "auth", "token": "{token}"')  # malformed JSON
        await ws_call(first=json.dumps({"type": "auth", "token": token * 40}))  # too long
    # A request aiohttp cannot even parse, carrying the token in its line and headers.
    # (Its 400 answer may quote the client's own bad line back to it: not collected.)
    host, port = url.removeprefix("http://").split(":")
    reader, writer = await asyncio.open_connection(host, int(port))
    try:
        writer.write(
            f"POST /api/estop?token={TOKEN} HTTP/1.1\r\nHost: {host}\r\n"
            f"Authorization: Bearer {TOKEN}\r\nBroken header {TOKEN}\r\n"
            f"Content-Length: nope-{TOKEN}\r\n\r\n".encode()
        )
        await writer.drain()
        answer = await asyncio.wait_for(reader.read(65536), 2)
        assert answer.split(b"\r\n", 1)[0].endswith(b" 400 Bad Request"), answer
    finally:
        writer.close()
        with contextlib.suppress(ConnectionError):
            await writer.wait_closed()
    return answers


def leaks(text: str) -> list[str]:
    return [t for t in (TOKEN, WRONG) if t in text]


async def test_token_never_in_a_log_nor_an_answer_in_process(
    sim: Sim, http: aiohttp.ClientSession, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG)
    # Whatever the site's logging says, the access log must not be the leak.
    caplog.set_level(logging.DEBUG, logger="aiohttp.access")
    async with running_daemon(sim) as daemon, running_api(daemon, token=TOKEN) as api:
        answers = await offer_the_token_every_way(http, api.url)
    records = caplog.records
    assert any(r.name == "aiohttp.access" for r in records), "no access log: a vacuous check"
    text = "\n".join(
        [caplog.text]
        + [str(r.args) for r in records]
        + [str(r.exc_info[1]) for r in records if r.exc_info]
    )
    assert not leaks(text), [r.getMessage() for r in records if leaks(r.getMessage() + str(r.args))]
    assert not leaks("\n".join(answers)), [a for a in answers if leaks(a)]


async def test_token_never_in_the_output_of_a_daemon_process(
    sim: Sim, http: aiohttp.ClientSession, lupin_home: Path
) -> None:
    proc = await MergedDaemonProcess.spawn(
        sim, lupin_home, "--log-level", "debug", env={"LUPIN_TOKEN": TOKEN}
    )
    try:
        await proc.ready()
        await proc.wait_for_line("(token required)")
        answers = await offer_the_token_every_way(http, proc.url)
        assert await proc.stop() == 0
    finally:
        await proc.close()
    assert "DEBUG" in proc.log, "the daemon logged nothing at debug: a vacuous check"
    assert not leaks(proc.log), [line for line in proc.lines if leaks(line)]
    assert not leaks("\n".join(answers))


# -- over-rate clients are throttled; the tick does not notice --------------------------------

FLOOD_S = 2.0
TICK_HZ = 100.0
NOMINAL = 1 / TICK_HZ


@pytest.fixture()
async def daemon_process(lupin_home: Path) -> AsyncIterator[MergedDaemonProcess]:
    """``lupin run`` on ``lupin sim``, each in its own process, away from the test's load."""
    sim = await SimProcess.spawn(lupin_home)
    try:
        proc = await MergedDaemonProcess.spawn_on(sim.path, lupin_home)
        try:
            await proc.ready()
            yield proc
            assert await proc.stop() == 0
        finally:
            await proc.close()
    finally:
        await sim.close()


async def ws_flood(url: str, seconds: float, per_second: float) -> dict[str, int]:
    """One client sending id'd twists at ``per_second`` for ``seconds``; counts the answers."""
    counts = {"sent": 0, "ok": 0, "rate_limited": 0, "other": 0, "after_ok": 0}
    frame = {"type": "twist", "source": "manual", "linear_x": 0.05}
    async with aiohttp.ClientSession() as session, session.ws_connect(url + "/api/ws") as ws:
        assert (await ws.receive_json(timeout=3))["type"] == "hello"

        async def read() -> None:
            async for msg in ws:
                data = json.loads(msg.data)
                if data["type"] == "reply" and data["ok"]:
                    counts["ok"] += 1
                    counts["after_ok"] += data["id"] == "after"
                elif data["type"] == "reply" and data["error"]["code"] == "rate_limited":
                    counts["rate_limited"] += 1
                elif data["type"] != "state":
                    counts["other"] += 1

        reader = asyncio.create_task(read())
        loop = asyncio.get_running_loop()
        start = loop.time()
        while (now := loop.time()) - start < seconds:
            due = int((now - start) * per_second) + 1
            while counts["sent"] < due:
                await ws.send_str(json.dumps({**frame, "id": counts["sent"]}))
                counts["sent"] += 1
            await asyncio.sleep(0.002)
        await asyncio.sleep(0.3)  # the last answers
        # Throttled, not thrown out: after a pause the same socket is served again.
        await asyncio.sleep(1.0)
        await ws.send_str(json.dumps({**frame, "id": "after"}))
        await asyncio.sleep(0.3)
        reader.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await reader
        counts["open"] = int(not ws.closed)
    return counts


async def http_flood(url: str, seconds: float, clients: int) -> dict[int, int]:
    """``clients`` loops, each posting twists or reading state back to back; status counts."""
    statuses: dict[int, int] = {}
    deadline = asyncio.get_running_loop().time() + seconds
    connector = aiohttp.TCPConnector(limit=clients)
    async with aiohttp.ClientSession(connector=connector) as session:

        async def hammer(n: int) -> None:
            while asyncio.get_running_loop().time() < deadline:
                if n % 2:
                    body = {"source": "auto", "linear_x": 0.05}
                    ctx = session.post(url + "/api/base/twist", json=body)
                else:
                    ctx = session.get(url + "/api/state")
                async with ctx as resp:
                    await resp.read()
                    statuses[resp.status] = statuses.get(resp.status, 0) + 1

        await asyncio.gather(*(hammer(n) for n in range(clients)))
    return statuses


async def test_over_rate_clients_are_throttled_and_the_tick_keeps_its_rate(
    http: aiohttp.ClientSession, daemon_process: MergedDaemonProcess
) -> None:
    url = daemon_process.url
    robot = await get_json(http, url + "/api/robot")
    assert robot["state_hz"] > 0
    # Baseline.
    m0, t0 = await scrape(http, url), time.monotonic()
    await asyncio.sleep(1.0)
    m1, t1 = await scrape(http, url), time.monotonic()

    # Three WebSocket clients at 10x their budget (50 frames/s, burst 50) each.
    rate, burst = 50.0, 50.0
    results = await asyncio.gather(*(ws_flood(url, FLOOD_S, 10 * rate) for _ in range(3)))
    m2, t2 = await scrape(http, url), time.monotonic()

    # Then sixteen HTTP clients back to back.
    statuses = await http_flood(url, FLOOD_S, 16)
    m3, t3 = await scrape(http, url), time.monotonic()

    for counts in results:
        assert counts["sent"] >= 0.9 * 10 * rate * FLOOD_S, counts
        assert counts["rate_limited"] > 0.5 * counts["sent"], counts
        # Accepted: no more than the budget allows over the flood (plus the one after).
        assert counts["ok"] <= burst + rate * (FLOOD_S + 0.5) + 1, counts
        assert counts["ok"] >= 0.5 * rate * FLOOD_S, counts  # throttled, not starved
        assert counts["other"] == 0, counts
        assert counts["open"] == 1 and counts["after_ok"] == 1, counts
    assert sum(statuses.values()) > 500, statuses  # really a flood
    assert set(statuses) == {200}, statuses

    for name, (a, b, ta, tb) in {
        "baseline": (m0, m1, t0, t1),
        "websocket flood": (m1, m2, t1, t2),
        "http flood": (m2, m3, t2, t3),
    }.items():
        hz = tick_rate(a, b, tb - ta)
        on_time = periods_within(a, b, 1.5 * NOMINAL)
        assert hz >= 0.9 * TICK_HZ, f"{name}: the tick ran at {hz:.1f} Hz"
        assert on_time >= 0.95, f"{name}: only {on_time:.1%} of tick periods within 1.5x"
    assert "Traceback" not in daemon_process.log
