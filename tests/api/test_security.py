"""Token, Origin, TLS and secrets: who may command the robot, and what never reaches a log."""

from __future__ import annotations

import datetime
import logging
import ssl
from pathlib import Path

import aiohttp
import pytest
from aiohttp import web

from lupin.api import ApiServer
from lupin.api.routes import ROUTES
from lupin.api.security import is_foreign_origin, resolve_token
from lupin.api.ws import CLOSE_UNAUTHORIZED, WsSettings
from lupin.daemon import Daemon

from .conftest import TOKEN, start_api
from .helpers import call, error_code

AUTH = {"Authorization": f"Bearer {TOKEN}"}
PARAMS = {"{joint}": "elbow_flex", "{preset}": "home", "{pose}": "p"}


def concrete(path: str) -> str:
    for key, value in PARAMS.items():
        path = path.replace(key, value)
    return path


MUTATING = [(r.method, concrete(r.path)) for r in ROUTES if r.mutating]


def test_every_mutating_route_is_covered() -> None:
    assert len(MUTATING) == 11
    assert {m for m, _ in MUTATING} == {"POST", "PUT", "DELETE"}


def test_env_token_wins_over_the_profile() -> None:
    assert resolve_token("from-profile", {"LUPIN_TOKEN": "from-env"}) == "from-env"
    assert resolve_token("from-profile", {}) == "from-profile"
    assert resolve_token(None, {"LUPIN_TOKEN": ""}) is None


@pytest.mark.parametrize(
    ("origin", "host", "foreign"),
    [
        (None, "127.0.0.1:8080", False),
        ("http://127.0.0.1:8080", "127.0.0.1:8080", False),
        ("http://robot.local", "robot.local:80", False),
        ("http://ROBOT.local:8080", "robot.local:8080", False),
        ("http://evil.example", "127.0.0.1:8080", True),
        ("http://127.0.0.1:9999", "127.0.0.1:8080", True),
        ("http://localhost:8080", "127.0.0.1:8080", True),
        ("https://127.0.0.1:8080", "127.0.0.1:8080", False),
        ("null", "127.0.0.1:8080", True),
        ("file://", "127.0.0.1:8080", True),
    ],
)
def test_origin_check(origin: str | None, host: str, foreign: bool) -> None:
    from aiohttp.test_utils import make_mocked_request

    headers = {"Host": host} | ({"Origin": origin} if origin else {})
    request: web.Request = make_mocked_request("POST", "/api/estop", headers=headers)
    assert is_foreign_origin(request) is foreign


# -- HTTP ------------------------------------------------------------------------------


async def test_every_mutating_request_needs_the_token(
    http: aiohttp.ClientSession, api_token: ApiServer, daemon: Daemon
) -> None:
    for method, path in MUTATING:
        for headers in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": TOKEN}):
            async with http.request(method, api_token.url + path, headers=headers) as resp:
                assert resp.status == 401, (method, path, headers)
                assert resp.headers["WWW-Authenticate"].startswith("Bearer")
                assert error_code(await resp.json()) == "unauthorized"
    assert not daemon.estop and daemon.arm.torque_summary.value == "off"
    # With the token the same requests get past auth (to their own answers).
    status, data = await call(
        http, api_token, "POST", "/api/estop", {"engaged": True}, headers=AUTH
    )
    assert (status, data) == (200, {"engaged": True})


async def test_reads_stay_open_with_a_token(
    http: aiohttp.ClientSession, api_token: ApiServer
) -> None:
    for path in ("/api/health", "/api/state", "/api/robot", "/api/openapi.json", "/metrics", "/"):
        async with http.get(api_token.url + path) as resp:
            assert resp.status == 200, path


async def test_foreign_origin_refused_on_mutations(
    http: aiohttp.ClientSession, api: ApiServer, daemon: Daemon
) -> None:
    evil = {"Origin": "http://evil.example"}
    status, data = await call(http, api, "POST", "/api/estop", {"engaged": True}, headers=evil)
    assert status == 403 and error_code(data) == "foreign_origin"
    assert not daemon.estop
    same = {"Origin": api.url}
    assert (await call(http, api, "POST", "/api/estop", {"engaged": True}, headers=same))[0] == 200


# -- WebSocket ---------------------------------------------------------------------------


async def test_ws_foreign_origin_refused_before_upgrade(
    http: aiohttp.ClientSession, api: ApiServer, api_token: ApiServer
) -> None:
    for server, extra in ((api, {}), (api_token, AUTH)):
        with pytest.raises(aiohttp.WSServerHandshakeError) as err:
            await http.ws_connect(
                server.url + "/api/ws", headers={"Origin": "http://evil.example", **extra}
            )
        assert err.value.status == 403


async def test_ws_same_origin_accepted(http: aiohttp.ClientSession, api: ApiServer) -> None:
    async with http.ws_connect(api.url + "/api/ws", headers={"Origin": api.url}) as ws:
        assert (await ws.receive_json(timeout=2))["type"] == "hello"


async def test_ws_token_as_subprotocol(http: aiohttp.ClientSession, api_token: ApiServer) -> None:
    # What a browser does: new WebSocket(url, ["lupin.v1", "bearer." + token]).
    async with http.ws_connect(
        api_token.url + "/api/ws", protocols=("lupin.v1", f"bearer.{TOKEN}")
    ) as ws:
        assert ws.protocol == "lupin.v1"  # the token is not echoed back
        assert (await ws.receive_json(timeout=2))["type"] == "hello"
        assert (await ws.receive_json(timeout=2))["type"] == "state"


async def test_ws_wrong_subprotocol_token_is_401(
    http: aiohttp.ClientSession, api_token: ApiServer
) -> None:
    with pytest.raises(aiohttp.WSServerHandshakeError) as err:
        await http.ws_connect(api_token.url + "/api/ws", protocols=("lupin.v1", "bearer.nope"))
    assert err.value.status == 401


async def test_ws_token_as_first_frame(http: aiohttp.ClientSession, api_token: ApiServer) -> None:
    async with http.ws_connect(api_token.url + "/api/ws") as ws:
        await ws.send_json({"type": "auth", "token": TOKEN, "id": "a1"})
        assert await ws.receive_json(timeout=2) == {
            "type": "reply",
            "id": "a1",
            "ok": True,
            "result": {"ok": True},
        }
        assert (await ws.receive_json(timeout=2))["type"] == "hello"


async def test_ws_without_auth_gets_nothing_and_is_closed(
    http: aiohttp.ClientSession, api_token: ApiServer, daemon: Daemon
) -> None:
    async with http.ws_connect(api_token.url + "/api/ws") as ws:
        await ws.send_json({"type": "estop", "engaged": True, "id": 1})
        frame = await ws.receive_json(timeout=2)
        assert frame["type"] == "error" and frame["error"]["code"] == "unauthorized"
        msg = await ws.receive(timeout=2)
        assert msg.type == aiohttp.WSMsgType.CLOSE and msg.data == CLOSE_UNAUTHORIZED
    async with http.ws_connect(api_token.url + "/api/ws") as ws:
        await ws.send_json({"type": "auth", "token": "wrong"})
        frame = await ws.receive_json(timeout=2)
        assert frame["error"] == {"code": "unauthorized", "message": "wrong token"}
    assert not daemon.estop


async def test_ws_auth_timeout(http: aiohttp.ClientSession, daemon: Daemon) -> None:
    server = await start_api(daemon, token=TOKEN, ws=WsSettings(auth_timeout_s=0.2))
    try:
        async with http.ws_connect(server.url + "/api/ws") as ws:
            assert (await ws.receive_json(timeout=2))["error"]["code"] == "unauthorized"
            assert (await ws.receive(timeout=2)).type == aiohttp.WSMsgType.CLOSE
    finally:
        await server.stop()


# -- secrets in logs, TLS -------------------------------------------------------------------


async def test_token_never_logged(
    http: aiohttp.ClientSession, api_token: ApiServer, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG)
    wrong = "wrong-4c1d8e2f9a7b"
    for token in (TOKEN, wrong):
        hdrs = {"Authorization": f"Bearer {token}"}
        await call(http, api_token, "POST", "/api/estop", {"engaged": False}, headers=hdrs)
        await call(http, api_token, "POST", "/api/nope", {"x": 1}, headers=hdrs)
        for protocols in ((f"bearer.{token}",), ("other", f"bearer.{token}")):
            try:
                async with http.ws_connect(api_token.url + "/api/ws", protocols=protocols) as ws:
                    await ws.receive(timeout=2)
            except aiohttp.WSServerHandshakeError:
                pass
        async with http.ws_connect(api_token.url + "/api/ws") as ws:
            await ws.send_json({"type": "auth", "token": token})
            await ws.receive(timeout=2)
    text = caplog.text + "".join(str(r.args) for r in caplog.records)
    assert caplog.records, "nothing was logged at all: the check would be vacuous"
    assert TOKEN not in text and wrong not in text


def _self_signed(tmp: Path) -> tuple[str, str]:
    crypto = pytest.importorskip("cryptography")
    del crypto
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "127.0.0.1")])
    now = datetime.datetime.now(datetime.UTC)
    import ipaddress

    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=1))
        .not_valid_after(now + datetime.timedelta(days=1))
        .add_extension(
            x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
            critical=False,
        )
        .sign(key, hashes.SHA256())
    )
    cert_path, key_path = tmp / "cert.pem", tmp / "key.pem"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_path.write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )
    )
    return str(cert_path), str(key_path)


async def test_tls_from_configured_cert_and_key(daemon: Daemon, tmp_path: Path) -> None:
    cert, key = _self_signed(tmp_path)
    server = await start_api(daemon, tls_cert=cert, tls_key=key)
    try:
        assert server.url.startswith("https://127.0.0.1:")
        trust = ssl.create_default_context(cafile=cert)
        async with aiohttp.ClientSession() as session:
            async with session.get(server.url + "/api/health", ssl=trust) as resp:
                assert resp.status == 200
            async with session.ws_connect(server.url + "/api/ws", ssl=trust) as ws:
                assert (await ws.receive_json(timeout=2))["type"] == "hello"
            plain = server.url.replace("https://", "http://")
            with pytest.raises(aiohttp.ClientError):
                async with session.get(plain + "/api/health") as resp:
                    await resp.read()
    finally:
        await server.stop()


async def test_default_bind_is_loopback(api: ApiServer) -> None:
    assert api.config.host == "127.0.0.1" and api.url.startswith("http://127.0.0.1:")
