"""Shared pieces of the reliability suite: daemon and API contexts, a per-tick recorder,
/metrics parsing, and the subprocess daemon.

Everything here judges the robot from outside where it can: the packets the
simulated servos received (``sim.bus``), the HTTP API, /metrics and the log.
The one inside view is :class:`TickLog`, hooked on ``ControlLoop.on_state``,
which records which servos answered each tick's SYNC_READ: a per-servo answer
rate that the bus counters (totals) cannot give.
"""

from __future__ import annotations

import asyncio
import contextlib
import re
import signal
import socket
from collections.abc import AsyncIterator, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import aiohttp

from lupin import control_table as ct
from lupin.api import ApiServer
from lupin.api.ws import WsSettings
from lupin.daemon import Daemon, DaemonOptions
from lupintest.harness import Sim, child_env, lupin_cmd

TORQUE = ct.REGISTERS["torque_enable"].address
GOAL_POS = ct.REGISTERS["goal_position"].address
GOAL_SPEED = ct.REGISTERS["goal_speed"].address
ARM = [1, 2, 3, 4, 5, 6]
WHEELS = [7, 9]
ALL = ARM + WHEELS
TOKEN = "tok-rel-0d4c8e2a6b1f3957c0e8a4d2b6f1c3e5"


# -- in-process daemon and API ---------------------------------------------------------


@contextlib.asynccontextmanager
async def running_daemon(sim: Sim, **options: Any) -> AsyncIterator[Daemon]:
    opts = DaemonOptions(bus_port=sim.path, auto_home=False, **options)
    d = Daemon(sim.profile, opts)
    await d.start()
    try:
        assert await d.wait_ready(3.0), "no complete joint state from the sim"
        yield d
    finally:
        await d.stop()


@contextlib.asynccontextmanager
async def running_api(
    daemon: Daemon, *, token: str | None = None, ws: WsSettings | None = None
) -> AsyncIterator[ApiServer]:
    config = daemon.profile.api.model_copy(update={"port": 0, "token": token})
    server = ApiServer(daemon.services, config, env={}, ws_settings=ws)
    await server.start()
    try:
        yield server
    finally:
        await server.stop()


async def get_json(http: aiohttp.ClientSession, url: str) -> Any:
    async with http.get(url) as resp:
        assert resp.status == 200, (url, resp.status)
        return await resp.json()


async def post(
    http: aiohttp.ClientSession,
    url: str,
    body: Any = None,
    headers: dict[str, str] | None = None,
) -> tuple[int, Any]:
    kwargs: dict[str, Any] = {} if body is None else {"json": body}
    async with http.post(url, headers=headers or {}, **kwargs) as resp:
        return resp.status, await resp.json(content_type=None)


# -- per-tick answers ----------------------------------------------------------------------


@dataclass
class TickLog:
    """Which servos answered each tick, and their error bytes (from ``ControlLoop.on_state``)."""

    daemon: Daemon
    ticks: list[tuple[float, frozenset[int]]] = field(default_factory=list)
    errors: dict[int, set[int]] = field(default_factory=dict)  # id -> error bytes seen
    stale_seen: set[int] = field(default_factory=set)

    def __post_init__(self) -> None:
        assert self.daemon.loop is not None
        self.daemon.loop.on_state.append(self._on_state)

    def _on_state(self, now: float) -> None:
        loop = self.daemon.loop
        assert loop is not None
        answered = frozenset(sid for sid, r in loop.readings.items() if r.misses == 0)
        self.ticks.append((now, answered))
        for sid, r in loop.readings.items():
            if r.misses:
                self.stale_seen.add(sid)
            if r.error:
                self.errors.setdefault(sid, set()).add(r.error)

    def window(self, t0: float, t1: float) -> list[frozenset[int]]:
        return [ids for t, ids in self.ticks if t0 <= t < t1]

    def rate(self, sid: int, t0: float, t1: float) -> float:
        """The fraction of ticks in [t0, t1) in which ``sid`` answered."""
        window = self.window(t0, t1)
        assert window, "no tick in the window"
        return sum(1 for ids in window if sid in ids) / len(window)

    def tick_hz(self, t0: float, t1: float) -> float:
        return len(self.window(t0, t1)) / (t1 - t0)


# -- /metrics ----------------------------------------------------------------------------

_SAMPLE = re.compile(r"^([a-zA-Z_:][a-zA-Z0-9_:]*(?:\{[^}]*\})?) (\S+)$")


def parse_metrics(text: str) -> dict[str, float]:
    """``{'name{labels}': value}`` for every sample line of a Prometheus text scrape."""
    out: dict[str, float] = {}
    for line in text.splitlines():
        if not line or line.startswith("#"):
            continue
        match = _SAMPLE.match(line)
        assert match, f"not a Prometheus sample line: {line!r}"
        out[match.group(1)] = float(match.group(2))
    return out


async def scrape(http: aiohttp.ClientSession, base_url: str) -> dict[str, float]:
    async with http.get(base_url + "/metrics") as resp:
        assert resp.status == 200
        return parse_metrics(await resp.text())


def failures(metrics: dict[str, float]) -> dict[str, float]:
    prefix = 'lupin_bus_failures_total{kind="'
    return {k[len(prefix) : -2]: v for k, v in metrics.items() if k.startswith(prefix)}


def grew(before: dict[str, float], after: dict[str, float], kinds: Iterable[str]) -> set[str]:
    """The failure kinds among ``kinds`` whose counter grew between two scrapes."""
    b, a = failures(before), failures(after)
    return {k for k in kinds if a.get(k, 0) > b.get(k, 0)}


# -- the daemon as a process -----------------------------------------------------------------


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class DaemonProcess:
    """``lupin run`` as a child process against an in-test sim; stderr kept line by line."""

    def __init__(self, proc: asyncio.subprocess.Process, port: int) -> None:
        self.proc = proc
        self.port = port
        self.url = f"http://127.0.0.1:{port}"
        self.lines: list[str] = []
        self._reader = asyncio.create_task(self._read(), name="daemon-stderr")

    @classmethod
    async def spawn(
        cls,
        sim: Sim,
        home: Path,
        *args: str,
        port: int | None = None,
        env: dict[str, str] | None = None,
    ) -> DaemonProcess:
        port = port or free_port()
        proc = await asyncio.create_subprocess_exec(
            *lupin_cmd("run", "--port", str(port), "--bus-port", sim.path, *args),
            stdout=asyncio.subprocess.DEVNULL,
            stderr=asyncio.subprocess.PIPE,
            env=child_env(home) | (env or {}),
        )
        return cls(proc, port)

    async def _read(self) -> None:
        assert self.proc.stderr is not None
        while line := await self.proc.stderr.readline():
            self.lines.append(line.decode(errors="replace"))

    @property
    def log(self) -> str:
        return "".join(self.lines)

    async def wait_for_line(self, needle: str, timeout: float = 15.0, start: int = 0) -> int:
        """Index of the first line from ``start`` on containing ``needle``."""
        async with asyncio.timeout(timeout):
            while True:
                for i in range(start, len(self.lines)):
                    if needle in self.lines[i]:
                        return i
                if self._reader.done():
                    raise AssertionError(f"daemon ended before {needle!r}:\n{self.log}")
                await asyncio.sleep(0.01)

    async def ready(self, timeout: float = 15.0) -> None:
        await self.wait_for_line("ready:", timeout)

    def rss_kib(self) -> int:
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
        raise AssertionError("no VmRSS line")

    async def stop(self, sig: int = signal.SIGTERM, timeout: float = 5.0) -> int:
        if self.proc.returncode is None:
            self.proc.send_signal(sig)
        try:
            async with asyncio.timeout(timeout):
                code = await self.proc.wait()
        finally:
            await self.close()
        return code

    async def close(self) -> None:
        """Make sure the process is gone and its stderr drained (idempotent)."""
        if self.proc.returncode is None:
            self.proc.kill()
            await self.proc.wait()
        with contextlib.suppress(asyncio.CancelledError, TimeoutError):
            await asyncio.wait_for(self._reader, 2.0)


# -- security, soak, shutdown and restart (appended) --------------------------------------


class MergedDaemonProcess(DaemonProcess):
    """``lupin run`` with stdout and stderr in one captured stream: nothing it prints escapes."""

    @classmethod
    async def spawn(
        cls,
        sim: Sim,
        home: Path,
        *args: str,
        port: int | None = None,
        env: dict[str, str] | None = None,
    ) -> DaemonProcess:
        return await cls.spawn_on(sim.path, home, *args, port=port, env=env)

    @classmethod
    async def spawn_on(
        cls,
        bus_port: str,
        home: Path,
        *args: str,
        port: int | None = None,
        env: dict[str, str] | None = None,
    ) -> MergedDaemonProcess:
        port = port or free_port()
        proc = await asyncio.create_subprocess_exec(
            *lupin_cmd("run", "--port", str(port), "--bus-port", bus_port, *args),
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.STDOUT,
            env=child_env(home) | (env or {}),
        )
        return cls(proc, port)

    async def _read(self) -> None:
        assert self.proc.stdout is not None
        while line := await self.proc.stdout.readline():
            self.lines.append(line.decode(errors="replace"))


@dataclass
class SimProcess:
    """``lupin sim`` in its own process: a bus whose timing no test-side load can disturb."""

    proc: asyncio.subprocess.Process
    path: str

    @classmethod
    async def spawn(cls, home: Path) -> SimProcess:
        proc = await asyncio.create_subprocess_exec(
            *lupin_cmd("sim"),
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.DEVNULL,
            env=child_env(home),
        )
        assert proc.stdout is not None
        try:
            async with asyncio.timeout(15):
                path = (await proc.stdout.readline()).decode().strip()
        except BaseException:
            proc.kill()
            await proc.wait()
            raise
        assert path.startswith("/dev/"), f"lupin sim printed {path!r}, not a pty path"
        return cls(proc, path)

    async def close(self) -> None:
        if self.proc.returncode is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                async with asyncio.timeout(5):
                    await self.proc.wait()
            except TimeoutError:
                self.proc.kill()
                await self.proc.wait()


def period_buckets(metrics: dict[str, float]) -> dict[float, float]:
    """``{upper bound (s): cumulative count}`` of the tick-period histogram of one scrape."""
    prefix = 'lupin_tick_period_seconds_bucket{le="'
    out: dict[float, float] = {}
    for key, value in metrics.items():
        if key.startswith(prefix):
            out[float(key[len(prefix) : -2])] = value
    return out


def periods_within(before: dict[str, float], after: dict[str, float], bound_s: float) -> float:
    """The fraction of tick periods between two scrapes that were at most ``bound_s`` long.

    ``bound_s`` must be one of the histogram's bucket bounds.
    """
    b, a = period_buckets(before), period_buckets(after)
    inf = float("inf")
    total = a[inf] - b.get(inf, 0.0)
    assert total > 0, "no tick between the two scrapes"
    bound = min(a, key=lambda x: abs(x - bound_s))
    assert abs(bound - bound_s) < 1e-9, f"{bound_s} is not a bucket bound: {sorted(a)}"
    return (a[bound] - b.get(bound, 0.0)) / total


def tick_rate(before: dict[str, float], after: dict[str, float], seconds: float) -> float:
    """Ticks per second between two scrapes ``seconds`` apart."""
    return (after["lupin_ticks_total"] - before["lupin_ticks_total"]) / seconds
