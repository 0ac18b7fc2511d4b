"""Keep the API token (and whatever a client mistypes for it) out of the log.

The token rides in headers, and clients put tokens in query strings whatever
the docs say. Two aiohttp log paths would copy those into the journal:

* the access log's default format writes the request line (``%r``, query
  string included) and the ``Referer`` header: :class:`SafeAccessLogger`
  writes method, path, status, size and time only;
* a request aiohttp cannot parse (a header with a stray control byte, say a
  token pasted with one) is logged on ``aiohttp.server`` at ERROR with a
  traceback whose message quotes the offending line, ``Authorization`` header
  included. :class:`MalformedRequestFilter` turns that into one INFO line that
  names the client and the kind of error, never the bytes; it is bad input
  answered 400, not a daemon fault.
"""

from __future__ import annotations

import logging

from aiohttp import web
from aiohttp.abc import AbstractAccessLogger
from aiohttp.http_exceptions import HttpProcessingError

SERVER_LOGGER = "aiohttp.server"


class SafeAccessLogger(AbstractAccessLogger):
    """``remote "METHOD /path" status bytes seconds``: no query string, no header."""

    def log(self, request: web.BaseRequest, response: web.StreamResponse, time: float) -> None:
        self.logger.info(
            '%s "%s %s" %d %d %.4f',
            request.remote,
            request.method,
            request.path,
            response.status,
            response.body_length,
            time,
        )

    @property
    def enabled(self) -> bool:
        return self.logger.isEnabledFor(logging.INFO)


class MalformedRequestFilter(logging.Filter):
    """Rewrite aiohttp's "Error handling request" for unparsable input, without its bytes."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, HttpProcessingError):
            peer = record.args[0] if isinstance(record.args, tuple) and record.args else "?"
            record.msg = "refused a malformed HTTP request from %s: %s (%d)"
            record.args = (peer, type(exc).__name__, exc.code)
            record.exc_info = None
            record.exc_text = None
            # Never louder than INFO; aiohttp's DEBUG for port scanners stays DEBUG.
            record.levelno = min(record.levelno, logging.INFO)
            record.levelname = logging.getLevelName(record.levelno)
        return True


_FILTER = MalformedRequestFilter()


def install() -> None:
    """Attach the filter to aiohttp's server logger (idempotent; process-wide)."""
    logging.getLogger(SERVER_LOGGER).addFilter(_FILTER)
