"""Load generator: WebSocket clients streaming state and paced HTTP requests against a daemon.

Run as a second process so the daemon's tick competes for the CPU the way it
would with a room full of HMIs open, not for a share of its own event loop::

    python bench/load.py http://127.0.0.1:PORT --ws-clients 20 --rps 200 --duration 25

It connects ``--ws-clients`` WebSocket clients to ``/api/ws`` (each receives the
20 Hz state stream and counts it, without parsing), then sends ``--rps`` HTTP
GETs per second on a fixed schedule, alternating ``/api/state`` and
``/api/health``, with at most ``--concurrency`` in flight (a request that would
exceed it is counted as ``skipped``, never queued up to burst later).

It always stops by itself: after ``--duration`` seconds, ``--max-requests``
requests, or SIGTERM/SIGINT, whichever comes first. Output is JSON lines on
stdout: ``{"event": "started", ...}`` once every client is connected, then
one summary document.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import signal
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import aiohttp
from benchlib import stats

PATHS = ("/api/state", "/api/health")


@dataclass
class Tally:
    sent: int = 0
    skipped: int = 0
    status: Counter[str] = field(default_factory=Counter)
    latencies: list[float] = field(default_factory=list)
    ws_frames: int = 0
    ws_bytes: int = 0
    ws_closed_early: int = 0


async def stream(ws: aiohttp.ClientWebSocketResponse, tally: Tally, stop: asyncio.Event) -> None:
    """Receive (and count) whatever the daemon pushes until told to stop."""
    async for msg in ws:
        if msg.type == aiohttp.WSMsgType.TEXT:
            tally.ws_frames += 1
            tally.ws_bytes += len(msg.data)
    if not stop.is_set():
        tally.ws_closed_early += 1


async def one_request(
    session: aiohttp.ClientSession, url: str, tally: Tally, slots: asyncio.Semaphore
) -> None:
    t0 = time.monotonic()
    try:
        async with session.get(url) as response:
            await response.read()
            tally.status[str(response.status)] += 1
    except (aiohttp.ClientError, TimeoutError) as exc:
        tally.status[type(exc).__name__] += 1
    finally:
        tally.latencies.append(time.monotonic() - t0)
        slots.release()


async def paced_requests(
    session: aiohttp.ClientSession, args: argparse.Namespace, tally: Tally, stop: asyncio.Event
) -> None:
    slots = asyncio.Semaphore(args.concurrency)
    tasks: set[asyncio.Task[None]] = set()
    start = time.monotonic()
    for i in range(args.max_requests):
        due = start + i / args.rps
        if due - start > args.duration or stop.is_set():
            break
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), max(0.0, due - time.monotonic()))
        if stop.is_set():
            break
        if slots.locked():
            tally.skipped += 1
            continue
        await slots.acquire()
        url = args.url + PATHS[i % len(PATHS)]
        task = asyncio.create_task(one_request(session, url, tally, slots))
        tasks.add(task)
        task.add_done_callback(tasks.discard)
        tally.sent += 1
    if tasks:
        await asyncio.wait(tasks, timeout=5.0)


async def run(args: argparse.Namespace) -> dict[str, Any]:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    tally = Tally()
    cpu0 = time.process_time()
    connector = aiohttp.TCPConnector(limit=args.concurrency + args.ws_clients)
    async with aiohttp.ClientSession(connector=connector) as session:
        sockets = [
            await session.ws_connect(f"{args.url}/api/ws", max_msg_size=0)
            for _ in range(args.ws_clients)
        ]
        readers = [asyncio.create_task(stream(ws, tally, stop)) for ws in sockets]
        print(json.dumps({"event": "started", "ws_clients": len(sockets)}), flush=True)
        t0 = time.monotonic()
        try:
            async with asyncio.timeout(args.duration + 10):
                await paced_requests(session, args, tally, stop)
        finally:
            wall = time.monotonic() - t0
            stop.set()
            for ws in sockets:
                await ws.close()
            await asyncio.gather(*readers, return_exceptions=True)
    return {
        "event": "summary",
        "url": args.url,
        "wall_s": round(wall, 3),
        "ws_clients": args.ws_clients,
        "ws_frames": tally.ws_frames,
        "ws_frames_per_client_per_s": round(tally.ws_frames / max(1, args.ws_clients) / wall, 2),
        "ws_mbytes": round(tally.ws_bytes / 1e6, 3),
        "ws_closed_early": tally.ws_closed_early,
        "http_target_rps": args.rps,
        "http_sent": tally.sent,
        "http_rps": round(tally.sent / wall, 1),
        "http_skipped_at_concurrency_limit": tally.skipped,
        "http_status": dict(tally.status),
        "http_latency_ms": stats.ms(tally.latencies),
        "load_process_cpu_s": round(time.process_time() - cpu0, 3),
    }


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("url", help="the daemon's base URL, e.g. http://127.0.0.1:8080")
    p.add_argument("--ws-clients", type=int, default=20)
    p.add_argument("--rps", type=float, default=200.0, help="HTTP requests per second")
    p.add_argument("--duration", type=float, default=25.0, help="seconds (a hard bound)")
    p.add_argument("--max-requests", type=int, default=20_000, help="a hard bound")
    p.add_argument("--concurrency", type=int, default=32, help="HTTP requests in flight at most")
    args = p.parse_args(argv)
    if args.rps <= 0 or args.duration <= 0 or args.max_requests < 1 or args.ws_clients < 0:
        p.error("--rps and --duration must be positive, --max-requests at least 1")
    args.url = args.url.rstrip("/")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    print(json.dumps(asyncio.run(run(parse_args(argv)))), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
