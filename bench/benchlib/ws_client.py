"""A WebSocket client of ``/api/ws`` that drains state frames and matches replies by ``id``."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
from typing import Any

import aiohttp


class WsClient:
    """One connection; :meth:`request` sends a command frame and awaits its reply."""

    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self.ws = ws
        self.states = 0
        self._ids = itertools.count(1)
        self._pending: dict[int, asyncio.Future[dict[str, Any]]] = {}
        self._reader = asyncio.create_task(self._read(), name="bench-ws-reader")

    @classmethod
    async def connect(cls, session: aiohttp.ClientSession, url: str) -> WsClient:
        ws = await session.ws_connect(f"{url}/api/ws", max_msg_size=0)
        return cls(ws)

    async def _read(self) -> None:
        async for msg in self.ws:
            if msg.type != aiohttp.WSMsgType.TEXT:
                continue
            frame = json.loads(msg.data)
            if frame.get("type") == "state":
                self.states += 1
            elif frame.get("type") == "reply":
                future = self._pending.pop(frame.get("id"), None)
                if future is not None and not future.done():
                    future.set_result(frame)

    def _register(self) -> tuple[int, asyncio.Future[dict[str, Any]]]:
        """A fresh ``id`` and the future its reply will resolve."""
        ident = next(self._ids)
        future: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
        self._pending[ident] = future
        return ident, future

    async def request(self, frame: dict[str, Any], timeout: float = 5.0) -> dict[str, Any]:
        """Send ``frame`` with a fresh ``id`` at once; the reply."""
        ident, future = self._register()
        await self.ws.send_str(json.dumps({**frame, "id": ident}))
        async with asyncio.timeout(timeout):
            return await future

    async def close(self) -> None:
        await self.ws.close()
        self._reader.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await self._reader
