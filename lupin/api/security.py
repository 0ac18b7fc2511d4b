"""Bearer token, Origin check and the WebSocket's browser-friendly credentials.

Policy:
* No token configured (neither ``api.token`` nor ``LUPIN_TOKEN``): everything is
  open, which is why the default bind is 127.0.0.1.
* With a token: every POST, PUT and DELETE needs ``Authorization: Bearer <token>``
  (401 otherwise), and so does the WebSocket. Reads (GET) stay open.
* A browser cannot set headers on a WebSocket, so the socket also takes the
  token as the subprotocol ``bearer.<token>`` or as its first frame
  ``{"type": "auth", "token": "..."}``.
* Any mutating request or WebSocket upgrade whose ``Origin`` names another
  host:port than the request's ``Host`` is refused 403: a page on another site
  must not be able to drive the robot through the operator's browser.

The token is compared in constant time and never logged.
"""

from __future__ import annotations

import hmac
import os
from collections.abc import Mapping
from urllib.parse import urlsplit

from aiohttp import web
from aiohttp.typedefs import Handler, Middleware

from lupin.api.errors import ApiError

TOKEN_ENV = "LUPIN_TOKEN"
SUBPROTOCOL_PREFIX = "bearer."
MUTATING = frozenset({"POST", "PUT", "DELETE", "PATCH"})
DEFAULT_PORTS = {"http": 80, "https": 443, "ws": 80, "wss": 443}


def resolve_token(configured: str | None, env: Mapping[str, str] | None = None) -> str | None:
    """``LUPIN_TOKEN`` wins over ``api.token`` (rotate it without editing the profile)."""
    env = os.environ if env is None else env
    return env.get(TOKEN_ENV) or configured or None


def token_matches(expected: str, offered: str | None) -> bool:
    if offered is None:
        return False
    return hmac.compare_digest(expected.encode(), offered.encode())


def bearer_of(request: web.BaseRequest) -> str | None:
    """The token of an ``Authorization: Bearer`` header, or None."""
    header = request.headers.get("Authorization", "")
    scheme, _, value = header.partition(" ")
    if scheme.lower() != "bearer" or not value.strip():
        return None
    return value.strip()


def subprotocol_token(request: web.BaseRequest) -> tuple[str | None, str | None]:
    """(token, the exact subprotocol string) from ``Sec-WebSocket-Protocol: bearer.<token>``."""
    for proto in request.headers.get("Sec-WebSocket-Protocol", "").split(","):
        proto = proto.strip()
        if proto.startswith(SUBPROTOCOL_PREFIX):
            return proto[len(SUBPROTOCOL_PREFIX) :], proto
    return None, None


def _host_port(netloc: str, scheme: str) -> tuple[str, int | None]:
    parts = urlsplit(f"//{netloc}")
    try:
        port = parts.port
    except ValueError:
        return netloc.lower(), None
    return (parts.hostname or "").lower(), port or DEFAULT_PORTS.get(scheme)


def is_foreign_origin(request: web.BaseRequest) -> bool:
    """True if an Origin header is present and its host:port differs from the Host's."""
    origin = request.headers.get("Origin")
    if origin is None:
        return False  # curl, the CLI, scripts: not a browser page
    if origin == "null":
        return True  # sandboxed frames and file:// pages
    parts = urlsplit(origin)
    if parts.scheme not in ("http", "https") or not parts.netloc:
        return True
    host = request.headers.get("Host")
    if not host:
        return True
    scheme = "https" if request.secure else "http"
    return _host_port(parts.netloc, parts.scheme) != _host_port(host, scheme)


def unauthorized(message: str) -> ApiError:
    return ApiError(401, "unauthorized", message, {"WWW-Authenticate": 'Bearer realm="lupin"'})


def check_bearer(request: web.BaseRequest, token: str | None) -> None:
    if token is None:
        return
    offered = bearer_of(request)
    if offered is None:
        raise unauthorized("this daemon needs a token: send Authorization: Bearer <token>")
    if not token_matches(token, offered):
        raise unauthorized("wrong token")


def security_middleware(token: str | None) -> Middleware:
    @web.middleware
    async def middleware(request: web.Request, handler: Handler) -> web.StreamResponse:
        routed = request.match_info.http_exception is None
        if routed and request.method in MUTATING:
            if is_foreign_origin(request):
                raise ApiError(403, "foreign_origin", "request from a page of another origin")
            check_bearer(request, token)
        return await handler(request)

    return middleware
