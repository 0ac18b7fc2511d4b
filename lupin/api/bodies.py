"""Request bodies and WebSocket frames: strict JSON in, a pydantic model out, or a 4xx.

Strict on purpose, because a robot moves on what is accepted here:
* ``NaN``, ``Infinity`` and numbers that overflow to infinity (``1e400``) are
  refused while parsing: Python's ``json`` would happily accept them;
* pydantic runs in strict mode, so ``"1.5"`` is not a number and ``1`` is not
  ``true``; unknown fields are refused by the models themselves;
* the error message names every offending field by its pydantic location.
"""

from __future__ import annotations

import json
import math
from typing import Any, TypeVar

from aiohttp import web
from pydantic import BaseModel, TypeAdapter, ValidationError

from lupin.api.errors import ApiError

M = TypeVar("M", bound=BaseModel)
T = TypeVar("T")


class _NotFinite(ValueError):
    pass


def _refuse_constant(name: str) -> Any:
    raise _NotFinite(f"{name} is not a number JSON allows; numbers must be finite")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise _NotFinite(f"{text} overflows to infinity; numbers must be finite")
    return value


def loads(text: str | bytes) -> Any:
    """Parse JSON, refusing NaN, infinities and overflowing numbers; raises ApiError 400."""
    try:
        return json.loads(text, parse_constant=_refuse_constant, parse_float=_finite_float)
    except _NotFinite as exc:
        raise ApiError(400, "invalid_json", str(exc)) from None
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        raise ApiError(400, "invalid_json", f"body is not valid JSON: {exc}") from None


def describe(exc: ValidationError, tag: object = None) -> str:
    """``field.sub: message; other: message`` (pydantic locations, at most five).

    ``tag`` is a discriminated union's tag, dropped from the front of each location.
    """
    parts = []
    for err in exc.errors()[:5]:
        loc = err["loc"]
        if tag is not None and loc and loc[0] == tag:
            loc = loc[1:]
        where = ".".join(str(p) for p in loc) or "body"
        parts.append(f"{where}: {err['msg']}")
    more = len(exc.errors()) - 5
    if more > 0:
        parts.append(f"and {more} more")
    return "; ".join(parts)


def validate(model: type[M], data: Any) -> M:
    if not isinstance(data, dict):
        kind = type(data).__name__
        raise ApiError(400, "invalid_body", f"body must be a JSON object, got {kind}")
    try:
        return model.model_validate(data, strict=True)
    except ValidationError as exc:
        raise ApiError(400, "invalid_body", describe(exc)) from None


def validate_frame(adapter: TypeAdapter[T], data: Any) -> T:
    """A WebSocket frame: a JSON object validated against a ``type``-tagged union."""
    if not isinstance(data, dict):
        kind = type(data).__name__
        raise ApiError(400, "invalid_frame", f"a frame must be a JSON object, got {kind}")
    try:
        return adapter.validate_python(data, strict=True)
    except ValidationError as exc:
        raise ApiError(400, "invalid_frame", describe(exc, data.get("type"))) from None


def _is_json(content_type: str) -> bool:
    return content_type == "application/json" or content_type.endswith("+json")


async def read_json(request: web.Request) -> Any:
    """The body as JSON (``{}`` when empty). Oversized bodies raise 413 inside ``read``."""
    raw = await request.read()
    if not raw:
        return {}  # no body at all; whitespace is not JSON and is refused below
    # A JSON content type forces a CORS preflight on cross-origin browser requests,
    # so a foreign page cannot post a "simple" text/plain body to the robot.
    if not _is_json(request.content_type):
        raise ApiError(
            415,
            "unsupported_media_type",
            f"send the body as application/json (got {request.content_type or 'no type'})",
        )
    return loads(raw)


async def read_model(request: web.Request, model: type[M]) -> M:
    return validate(model, await read_json(request))


async def read_no_body(request: web.Request) -> None:
    """An endpoint without a body accepts nothing, or an empty JSON object."""
    data = await read_json(request)
    if data != {}:
        raise ApiError(400, "invalid_body", "this endpoint takes no body (or {})")
