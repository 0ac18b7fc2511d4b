"""Operations fixtures: the simulated bus on a pty in the test's loop, and a notify socket."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import tempfile
import time
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest

from lupintest.notify import NotifySocket


@pytest.fixture()
def notify_path() -> Iterator[str]:
    # AF_UNIX paths are limited to 108 bytes; pytest's tmp_path can be longer.
    with tempfile.TemporaryDirectory(prefix="lupin-notify-") as d:
        yield str(Path(d) / "notify.sock")


@pytest.fixture()
async def notify_socket(notify_path: str) -> AsyncIterator[NotifySocket]:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(notify_path)
    sock.setblocking(False)
    ns = NotifySocket(sock, notify_path)
    loop = asyncio.get_running_loop()

    async def receive() -> None:
        while True:
            data = await loop.sock_recv(sock, 4096)
            # time.monotonic: the clock the simulated bus stamps its packet log with.
            ns.messages.append((time.monotonic(), data.decode()))

    task = asyncio.create_task(receive(), name="notify-receiver")
    try:
        yield ns
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        sock.close()
