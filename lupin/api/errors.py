"""One error format for everything the API refuses: ``{"error": {"code", "message"}}``.

The middleware here is the last line: a service refusal keeps its status, an
aiohttp HTTP error (unknown path, wrong method, oversized body) gets the same
body shape with its headers kept (``Allow`` on a 405), and an unexpected
exception is logged with its traceback and answered 500 with the error body,
never a bare stack trace. Bad input must never reach that last branch; the
tests assert it is not logged.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Mapping

from aiohttp import web
from aiohttp.typedefs import Handler

from lupin.api_models import ErrorBody, ErrorResponse
from lupin.services import ServiceError

log = logging.getLogger(__name__)

# Codes for the errors aiohttp raises itself, before or around a handler.
HTTP_CODES: dict[int, str] = {
    400: "bad_request",
    401: "unauthorized",
    403: "forbidden",
    404: "not_found",
    405: "method_not_allowed",
    413: "body_too_large",
    415: "unsupported_media_type",
}
# Headers of an aiohttp HTTP error worth keeping on the rewritten response.
KEPT_HEADERS = ("Allow", "WWW-Authenticate")


class ApiError(Exception):
    """A refusal decided by the API layer itself (body, auth, origin)."""

    def __init__(
        self, status: int, code: str, message: str, headers: Mapping[str, str] | None = None
    ) -> None:
        super().__init__(message)
        self.status, self.code, self.message = status, code, message
        self.headers = dict(headers or {})


def error_body(code: str, message: str) -> ErrorResponse:
    return ErrorResponse(error=ErrorBody(code=code, message=message))


def error_response(
    status: int, code: str, message: str, headers: Mapping[str, str] | None = None
) -> web.Response:
    return web.Response(
        status=status,
        text=error_body(code, message).model_dump_json(),
        content_type="application/json",
        headers=headers,
    )


def _http_error(exc: web.HTTPException) -> web.Response:
    code = HTTP_CODES.get(exc.status, f"http_{exc.status}")
    if exc.status == 405 and isinstance(exc, web.HTTPMethodNotAllowed):
        allowed = ", ".join(sorted(exc.allowed_methods))
        message = f"{exc.method} is not allowed here; allowed: {allowed}"
    elif exc.status == 404:
        message = "no such endpoint"
    elif exc.status == 413:
        message = f"request body too large. {exc.text or ''}".strip()
    else:
        message = exc.text or exc.reason
    headers = {k: exc.headers[k] for k in KEPT_HEADERS if k in exc.headers}
    return error_response(exc.status, code, message, headers)


@web.middleware
async def error_middleware(request: web.Request, handler: Handler) -> web.StreamResponse:
    try:
        return await handler(request)
    except ApiError as exc:
        return error_response(exc.status, exc.code, exc.message, exc.headers)
    except ServiceError as exc:
        return error_response(exc.status, exc.code, exc.message)
    except web.HTTPException as exc:
        if exc.status < 400:
            raise
        return _http_error(exc)
    except (asyncio.CancelledError, ConnectionResetError):
        raise
    except Exception:
        # A bug, not bad input: say so in the log with the traceback (never the headers,
        # which may carry the token) and keep the error body shape for the client.
        log.exception("unhandled error in %s %s", request.method, request.path)
        return error_response(500, "internal", "internal error; the daemon log has the details")
