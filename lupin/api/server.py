"""The aiohttp application and its life cycle: build, bind (TLS when configured), stop.

``lupin run`` starts an :class:`ApiServer` right after the daemon and stops it
before the daemon, so no request can reach a daemon that is shutting down.
"""

from __future__ import annotations

import logging
import ssl
from collections.abc import Mapping

from aiohttp import web

from lupin.api import logsafe, routes, static
from lupin.api.contract import ApiServices
from lupin.api.errors import error_middleware
from lupin.api.metrics import CONTENT_TYPE, Metrics
from lupin.api.openapi import build_document
from lupin.api.security import resolve_token, security_middleware
from lupin.api.ws import WsHub, WsSettings
from lupin.config_models import ApiConfig

log = logging.getLogger(__name__)

HUB_KEY: web.AppKey[WsHub] = web.AppKey("ws_hub")
METRICS_KEY: web.AppKey[Metrics] = web.AppKey("metrics")
TOKEN_KEY: web.AppKey[str | None] = web.AppKey("token")
# Headers on every response: the HMI must not be framed by another page (a
# clickjacked E-stop button), nor content sniffed.
SECURITY_HEADERS = {
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Referrer-Policy": "no-referrer",
}


async def _openapi(request: web.Request) -> web.Response:
    services = request.app[routes.SERVICES_KEY]
    doc = build_document(services.robot(), token_required=request.app[TOKEN_KEY] is not None)
    return web.json_response(doc)


async def _metrics(request: web.Request) -> web.Response:
    hub = request.app[HUB_KEY]
    text = request.app[METRICS_KEY].render(
        request.app[routes.SERVICES_KEY].telemetry(), len(hub.connections), hub.replaced_total
    )
    return web.Response(body=text.encode(), headers={"Content-Type": CONTENT_TYPE})


async def _headers(request: web.Request, response: web.StreamResponse) -> None:
    for name, value in SECURITY_HEADERS.items():
        response.headers.setdefault(name, value)


def build_app(
    services: ApiServices,
    config: ApiConfig,
    *,
    token: str | None = None,
    ws_settings: WsSettings | None = None,
) -> web.Application:
    """The whole API as an aiohttp app; ``token`` None means no token is required."""
    app = web.Application(
        client_max_size=config.max_body_bytes,
        middlewares=[error_middleware, security_middleware(token)],
    )
    settings = ws_settings or WsSettings(
        state_hz=config.state_hz, max_msg_size=config.max_body_bytes
    )
    hub = WsHub(services, token, settings)
    app[routes.SERVICES_KEY] = services
    app[HUB_KEY] = hub
    app[TOKEN_KEY] = token
    app[METRICS_KEY] = Metrics(services.health().tick_hz)
    routes.add_routes(app)
    app.router.add_get("/api/openapi.json", _openapi, allow_head=False)
    app.router.add_get("/metrics", _metrics, allow_head=False)
    app.router.add_get("/api/ws", hub.handle, allow_head=False)
    static.add_routes(app)
    app.on_startup.append(hub.start)
    app.on_shutdown.append(hub.stop)
    app.on_response_prepare.append(_headers)
    return app


def tls_context(config: ApiConfig) -> ssl.SSLContext | None:
    if config.tls_cert is None or config.tls_key is None:
        return None
    context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    context.load_cert_chain(config.tls_cert, config.tls_key)
    return context


class ApiServer:
    """Binds the app to ``api.host:api.port`` (port 0 picks a free one; see :attr:`url`)."""

    def __init__(
        self,
        services: ApiServices,
        config: ApiConfig,
        *,
        env: Mapping[str, str] | None = None,
        ws_settings: WsSettings | None = None,
    ) -> None:
        self.config = config
        self.token = resolve_token(config.token, env)
        self.app = build_app(services, config, token=self.token, ws_settings=ws_settings)
        self.ssl = tls_context(config)
        self._runner: web.AppRunner | None = None
        self.url = ""

    @property
    def hub(self) -> WsHub:
        return self.app[HUB_KEY]

    async def start(self) -> str:
        """Listen; return the base URL with the real port."""
        logsafe.install()  # the token must not reach the log through aiohttp's own lines
        runner = web.AppRunner(
            self.app,
            handle_signals=False,
            shutdown_timeout=1.0,
            access_log_class=logsafe.SafeAccessLogger,
        )
        await runner.setup()
        site = web.TCPSite(runner, self.config.host, self.config.port, ssl_context=self.ssl)
        try:
            await site.start()
        except BaseException:
            await runner.cleanup()
            raise
        self._runner = runner
        host, port = runner.addresses[0][:2]
        host = f"[{host}]" if ":" in host else host
        self.url = f"{'https' if self.ssl else 'http'}://{host}:{port}"
        if self.token is None and self.config.host not in ("127.0.0.1", "localhost", "::1"):
            log.warning(
                "API on %s with no token: anyone on the network can move the robot",
                self.config.host,
            )
        return self.url

    async def stop(self) -> None:
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None
