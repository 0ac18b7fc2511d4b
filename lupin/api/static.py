"""The HMI's files: ``/`` is ``index.html``, ``/static/<file>`` the rest.

Read through :mod:`importlib.resources` from the ``lupin.hmi`` package, so a
wheel serves them as well as a checkout; file names are checked segment by
segment so no request can climb out of the ``static`` folder.
"""

from __future__ import annotations

import mimetypes
import re
from importlib import resources
from importlib.resources.abc import Traversable

from aiohttp import web

from lupin.api.errors import ApiError

PACKAGE = "lupin.hmi"
SEGMENT = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,99}$")  # no "..", no hidden files
# The HMI changes with the daemon; make the browser revalidate instead of caching stale JS.
HEADERS = {"Cache-Control": "no-cache"}


def static_root() -> Traversable:
    return resources.files(PACKAGE).joinpath("static")


def _file(root: Traversable, path: str) -> Traversable:
    parts = path.split("/")
    if not parts or not all(SEGMENT.match(p) and ".." not in p for p in parts):
        raise ApiError(404, "not_found", "no such file")
    node = root
    for part in parts:
        node = node.joinpath(part)
    if not node.is_file():
        raise ApiError(404, "not_found", "no such file")
    return node


def _respond(node: Traversable) -> web.Response:
    kind, _ = mimetypes.guess_type(node.name)
    kind = kind or "application/octet-stream"
    charset = "utf-8" if kind.startswith("text/") or kind.endswith(("javascript", "json")) else None
    return web.Response(body=node.read_bytes(), content_type=kind, charset=charset, headers=HEADERS)


async def index(request: web.Request) -> web.Response:
    return _respond(_file(static_root(), "index.html"))


async def static_file(request: web.Request) -> web.Response:
    return _respond(_file(static_root(), request.match_info["file"]))


def add_routes(app: web.Application) -> None:
    app.router.add_get("/", index, allow_head=False)
    app.router.add_get("/static/{file:.+}", static_file, allow_head=False)
