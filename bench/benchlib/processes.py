"""The simulator and the daemon as their own processes, started and always cleaned up.

* :func:`simulator`: ``python -m lupin sim --wire-pacing`` (prints its pty path first);
* :func:`daemon`: ``python -m lupin run --bus-port PTY --port 0 --pad none`` with
  ``LUPIN_AUTO_HOME=false`` and a temporary ``LUPIN_HOME``; its log goes to a file
  (a pipe nobody drains would stall the daemon's logging, and so its tick), which
  is read for ``API listening on URL`` and ``ready:``;
* :func:`cpu_seconds` and :func:`memory_kib`: another process's CPU and memory from /proc.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import re
import signal
import sys
import time
from collections.abc import AsyncIterator, Mapping
from dataclasses import dataclass
from pathlib import Path

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
URL_LINE = re.compile(r"API listening on (\S+)")
# Inherited from whoever runs the benchmark, they would change what is measured.
SCRUBBED = ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID", "JOURNAL_STREAM", "LUPIN_TOKEN")


def lupin_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "lupin", *args]


def bench_env(home: Path, extra: Mapping[str, str] | None = None) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in SCRUBBED}
    env.update({"LUPIN_HOME": str(home), "LUPIN_AUTO_HOME": "false", "NO_COLOR": "1"})
    env.update(extra or {})
    return env


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a process, from /proc/PID/stat (1/CLK_TCK resolution)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


def memory_kib(pid: int) -> dict[str, int]:
    """VmRSS (resident now) and VmHWM (peak resident) of a process, in KiB."""
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            out[key] = int(value.split()[0])
    return out


async def terminate(proc: asyncio.subprocess.Process, grace: float = 10.0) -> int:
    """SIGTERM, wait up to ``grace`` seconds, then SIGKILL; the exit code."""
    if proc.returncode is None:
        with contextlib.suppress(ProcessLookupError):
            proc.send_signal(signal.SIGTERM)
        try:
            async with asyncio.timeout(grace):
                await proc.wait()
        except TimeoutError:
            with contextlib.suppress(ProcessLookupError):
                proc.kill()
            await proc.wait()
    assert proc.returncode is not None
    return proc.returncode


@dataclass
class SimProcess:
    path: str
    pid: int


@contextlib.asynccontextmanager
async def simulator(home: Path, *, wire_pacing: bool = True) -> AsyncIterator[SimProcess]:
    """``lupin sim`` (so101) in its own process until the block ends."""
    args = ["sim", "--profile", "so101", "--log-level", "warning"]
    proc = await asyncio.create_subprocess_exec(
        *lupin_cmd(*args, *(["--wire-pacing"] if wire_pacing else [])),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.DEVNULL,
        env=bench_env(home),
    )
    try:
        assert proc.stdout is not None
        async with asyncio.timeout(30):
            path = (await proc.stdout.readline()).decode().strip()
        if not path.startswith("/dev/"):
            raise RuntimeError(f"lupin sim did not print a pty path: {path!r}")
        yield SimProcess(path, proc.pid)
    finally:
        await terminate(proc)


@dataclass
class DaemonProcess:
    proc: asyncio.subprocess.Process
    url: str
    log: Path
    spawned_at: float  # time.monotonic() just before the spawn

    @property
    def pid(self) -> int:
        return self.proc.pid


def _read(log: Path) -> str:
    """The log so far (a small local file: reading it does not stall the loop)."""
    return log.read_text(errors="replace") if log.exists() else ""


async def _wait_for_log(proc: asyncio.subprocess.Process, log: Path, timeout: float) -> str:
    """The API URL once both ``API listening on`` and ``ready:`` are in the log."""
    deadline = time.monotonic() + timeout
    while True:
        text = _read(log)
        match = URL_LINE.search(text)
        if match and "ready:" in text:
            return match.group(1)
        if proc.returncode is not None:
            raise RuntimeError(f"lupin run exited {proc.returncode}:\n{text}")
        if time.monotonic() > deadline:
            raise RuntimeError(f"lupin run not ready after {timeout} s:\n{text}")
        await asyncio.sleep(0.02)


@contextlib.asynccontextmanager
async def daemon(
    home: Path,
    bus_port: str,
    *,
    config: Path | None = None,
    env: Mapping[str, str] | None = None,
    name: str = "daemon",
    timeout: float = 30.0,
) -> AsyncIterator[DaemonProcess]:
    """``lupin run`` on ``bus_port`` in its own process until the block ends (then SIGTERM)."""
    args = ["run", "--bus-port", bus_port, "--port", "0", "--pad", "none"]
    if config is not None:
        args += ["--config", str(config)]
    log = home / f"{name}.log"
    with log.open("wb") as sink:
        spawned_at = time.monotonic()
        proc = await asyncio.create_subprocess_exec(
            *lupin_cmd(*args),
            stdin=asyncio.subprocess.DEVNULL,
            stdout=sink,
            stderr=sink,
            env=bench_env(home, env),
        )
    try:
        url = await _wait_for_log(proc, log, timeout)
        yield DaemonProcess(proc, url, log, spawned_at)
    finally:
        code = await terminate(proc)
        if code not in (0, -signal.SIGTERM):
            print(f"warning: lupin run exited {code}; log in {log}", file=sys.stderr)


def site_config(home: Path, tick_hz: float) -> Path:
    """A ``--config`` site file that sets ``control.tick_hz``."""
    path = home / f"site-{tick_hz:g}hz.yaml"
    path.write_text(f"control:\n  tick_hz: {tick_hz:g}\n")
    return path
