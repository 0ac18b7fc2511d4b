"""The API's log guards: no query string or header in the access log, no echo of bad requests."""

from __future__ import annotations

import logging
import sys

import pytest
from aiohttp import web
from aiohttp.http_exceptions import BadHttpMessage
from aiohttp.test_utils import make_mocked_request

from lupin.api.logsafe import MalformedRequestFilter, SafeAccessLogger

SECRET = "tok-unit-3f9a1c7e5b2d"


def test_access_log_has_method_path_status_and_no_query_nor_header(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger="test.access")
    request = make_mocked_request(
        "POST",
        f"/api/estop?token={SECRET}",
        headers={"Authorization": f"Bearer {SECRET}", "Referer": f"http://x/?t={SECRET}"},
    )
    response = web.Response(status=401)
    logger = SafeAccessLogger(logging.getLogger("test.access"), "%r")
    assert logger.enabled
    logger.log(request, response, 0.0123)
    (record,) = caplog.records
    assert '"POST /api/estop" 401' in record.getMessage()
    assert SECRET not in record.getMessage()


def test_access_log_is_off_when_its_logger_is_quiet() -> None:
    quiet = logging.getLogger("test.access.quiet")
    quiet.setLevel(logging.WARNING)
    assert not SafeAccessLogger(quiet, "").enabled


def _record(exc: BaseException, level: int = logging.ERROR) -> logging.LogRecord:
    try:
        raise exc
    except BaseException:
        info = sys.exc_info()
    return logging.LogRecord(
        "aiohttp.server", level, __file__, 1, "Error handling request from %s", ("10.0.0.9",), info
    )


def test_a_malformed_request_becomes_one_line_without_its_bytes() -> None:
    line = f"Invalid header token: b'Authorization: Bearer {SECRET}\\x01'"
    record = _record(BadHttpMessage(line))
    assert MalformedRequestFilter().filter(record)
    text = logging.Formatter().format(record)
    assert SECRET not in text and "Traceback" not in text
    assert text == "refused a malformed HTTP request from 10.0.0.9: BadHttpMessage (400)"
    assert record.levelno == logging.INFO and record.levelname == "INFO"


def test_a_port_scanner_stays_at_debug() -> None:
    record = _record(BadHttpMessage("garbage"), logging.DEBUG)
    MalformedRequestFilter().filter(record)
    assert record.levelno == logging.DEBUG and record.levelname == "DEBUG"


def test_other_errors_keep_their_traceback() -> None:
    record = _record(RuntimeError("a bug"))
    assert MalformedRequestFilter().filter(record)
    assert record.levelno == logging.ERROR and record.exc_info is not None
    assert "a bug" in logging.Formatter().format(record)
