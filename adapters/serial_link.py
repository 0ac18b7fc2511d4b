"""The serial-port ByteLink on pyserial-asyncio, with the single-opener guard.

A serial port has no kernel-level exclusion: a second opener is not refused, it
interleaves packets on the bus that moves the robot (bring-up seed). So before
any byte is sent we scan /proc for another process holding the device open for
writing and refuse, naming its PID; then we open with an exclusive lock so two
Lupin processes cannot race past the scan.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
from collections.abc import Callable
from pathlib import Path

import serial
import serial_asyncio


class PortBusy(Exception):
    """Another process holds the serial port."""


class PortUnavailable(Exception):
    """The serial port cannot be opened (missing, permissions, not a tty)."""


def _writable(pid_dir: Path, fd: str) -> bool:
    # A reader cannot corrupt the bus, a writer can: the simulator keeps a
    # read-only handle on its own pty so the master side never sees a hang-up.
    try:
        for line in (pid_dir / "fdinfo" / fd).read_text().splitlines():
            if line.startswith("flags:"):
                return int(line.split()[1], 8) & os.O_ACCMODE != os.O_RDONLY
    except (OSError, ValueError):
        pass
    return True


def port_holders(device: str) -> list[tuple[int, str]]:
    """Processes other than this one with ``device`` open for writing: (pid, command)."""
    try:
        target = os.stat(os.path.realpath(device))
    except OSError:
        return []
    holders = []
    me = os.getpid()
    for pid_dir in Path("/proc").iterdir():
        if not pid_dir.name.isdigit() or int(pid_dir.name) == me:
            continue
        try:
            fds = list((pid_dir / "fd").iterdir())
        except OSError:
            continue
        for fd in fds:
            try:
                st = os.stat(fd)
            except OSError:
                continue
            if (st.st_rdev, st.st_ino, st.st_dev) == (target.st_rdev, target.st_ino, target.st_dev):
                if not _writable(pid_dir, fd.name):
                    continue
                try:
                    raw = (pid_dir / "cmdline").read_bytes()
                    cmd = raw.replace(b"\0", b" ").decode(errors="replace").strip()
                except OSError:
                    cmd = "?"
                holders.append((int(pid_dir.name), cmd))
                break
    return holders


def check_port_free(device: str) -> None:
    holders = port_holders(device)
    if holders:
        who = ", ".join(f"PID {pid} ({cmd or '?'})" for pid, cmd in holders)
        raise PortBusy(f"{device} is held by {who}; stop it first (one opener per bus)")


class _Receiver(asyncio.Protocol):
    def __init__(self, link: SerialLink) -> None:
        self.link = link

    def data_received(self, data: bytes) -> None:
        self.link._deliver(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self.link.lost = exc or ConnectionError("serial port closed")


class SerialLink:
    """ByteLink over a serial device (a real bus or a simulator's pty)."""

    def __init__(self, baud: int) -> None:
        self.baud = baud
        self.transport: asyncio.BaseTransport | None = None
        self.lost: Exception | None = None
        self._callback: Callable[[bytes], None] = lambda _data: None

    @classmethod
    async def open(cls, device: str, baud: int) -> SerialLink:
        """Open ``device`` exclusively, refusing (naming the PID) if another process holds it."""
        check_port_free(device)
        link = cls(baud)
        try:
            link.transport, _ = await serial_asyncio.create_serial_connection(
                asyncio.get_running_loop(),
                lambda: _Receiver(link),
                device,
                baudrate=baud,
                exclusive=True,
            )
        except serial.SerialException as exc:
            text = str(exc).lower()
            if "lock" in text or "resource temporarily" in text:
                raise PortBusy(f"{device} is locked by another process: {exc}") from None
            raise PortUnavailable(f"cannot open {device}: {exc}") from None
        return link

    def set_receiver(self, callback: Callable[[bytes], None]) -> None:
        self._callback = callback

    def _deliver(self, data: bytes) -> None:
        self._callback(data)

    def write(self, data: bytes) -> None:
        if self.lost is not None or self.transport is None:
            raise ConnectionError(f"serial link lost: {self.lost}")
        self.transport.write(data)  # type: ignore[attr-defined]

    async def close(self) -> None:
        if self.transport is not None:
            with contextlib.suppress(Exception):
                self.transport.close()
            self.transport = None
        # Let the transport's close callbacks run so the fd is really released.
        await asyncio.sleep(0)


async def open_link(device: str, baud: int, **_options: object) -> SerialLink:
    """The ``serial`` entry of the ``lupin.bus`` group."""
    return await SerialLink.open(device, baud)
