"""A fake systemd notify socket: bind it, hand its path to a child, see when READY=1 comes."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import time
from pathlib import Path


class NotifyListener:
    """An AF_UNIX datagram socket at ``path`` that records when each field first arrived."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.first: dict[str, float] = {}  # "READY=1" -> time.monotonic() of arrival
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_NONBLOCK)
        self._sock.bind(str(path))
        self._ready = asyncio.Event()
        self._task = asyncio.create_task(self._receive(), name="bench-notify")

    async def _receive(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            data = await loop.sock_recv(self._sock, 4096)
            now = time.monotonic()
            for field in data.decode(errors="replace").splitlines():
                self.first.setdefault(field, now)
                if field == "READY=1":
                    self._ready.set()

    async def ready_at(self, timeout: float) -> float:
        """The monotonic time READY=1 arrived (waits up to ``timeout`` s for it)."""
        async with asyncio.timeout(timeout):
            await self._ready.wait()
        return self.first["READY=1"]

    async def close(self) -> None:
        self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self._task
        self._sock.close()
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
