"""Footprint benchmark: the daemon's CPU and memory, idle and driving, and its start-up time.

Prints one JSON document (and writes ``bench/results/footprint.json``):

* **start_to_ready**: from spawning ``python -m lupin run`` to its ``READY=1`` on a
  notify socket this benchmark binds (``NOTIFY_SOCKET``, as systemd's
  ``Type=notify`` would); the daemon sends it after the first full joint state;
* **cpu** of the daemon process, idle (no client) and driving (one WebSocket
  client, as the HMI: receiving the 20 Hz state stream and sending a ``manual``
  twist at 10 Hz, a new value each time), from ``/proc/PID/stat``;
* **memory**: VmRSS after each phase and the peak (VmHWM), from ``/proc/PID/status``.

    python bench/footprint.py
    python bench/footprint.py --smoke
"""

from __future__ import annotations

import asyncio
import math
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import aiohttp
from benchlib import output, processes, stats
from benchlib.notify import NotifyListener
from benchlib.processes import DaemonProcess, cpu_seconds, memory_kib
from benchlib.ws_client import WsClient

NAME = "footprint"
SETTLE_S = 1.0  # after ready: boot heal reads the bus once more

METHOD = (
    "Simulator (python -m lupin sim --wire-pacing, so101, 1 Mbaud) in its own process; the "
    "daemon is python -m lupin run --bus-port PTY --port 0 --pad none (100 Hz tick, "
    "LUPIN_AUTO_HOME=false, temporary LUPIN_HOME) in another, so its /proc figures are its "
    "own. start_to_ready: time.monotonic() just before asyncio.create_subprocess_exec -> "
    "arrival of READY=1 on an AF_UNIX datagram socket bound by this benchmark and passed as "
    "NOTIFY_SOCKET (Python start-up and imports included), SPAWNS spawns one after the "
    "other. CPU %: utime+stime delta from /proc/PID/stat (1/100 s resolution) over the "
    "phase's wall time, 100 % = one core; the phase starts 1 s after ready. Idle: no client. "
    "Driving: one WebSocket client in this process, as the HMI drive pad: it receives the "
    "20 Hz state stream and sends {type: twist, source: manual} at 10 Hz with a new "
    "linear_x/angular_z each time (so the wheel goals change every message). Memory: VmRSS "
    "at the end of each phase, VmHWM (peak) at the end, from /proc/PID/status."
)


def cpu_phase(pid: int, t0: float, cpu0: float) -> dict[str, Any]:
    wall = time.monotonic() - t0
    cpu = cpu_seconds(pid) - cpu0
    return {
        "wall_s": round(wall, 3),
        "cpu_s": round(cpu, 3),
        "cpu_percent": round(100 * cpu / wall, 2),
        "rss_kib": memory_kib(pid).get("VmRSS"),
    }


async def idle(d: DaemonProcess, seconds: float) -> dict[str, Any]:
    t0, cpu0 = time.monotonic(), cpu_seconds(d.pid)
    await asyncio.sleep(seconds)
    return cpu_phase(d.pid, t0, cpu0)


async def driving(d: DaemonProcess, seconds: float) -> dict[str, Any]:
    async with aiohttp.ClientSession() as session:
        ws = await WsClient.connect(session, d.url)
        try:
            await asyncio.sleep(0.5)  # the hello and the first states: not part of the phase
            t0, cpu0 = time.monotonic(), cpu_seconds(d.pid)
            sent, i = 0, 0
            while time.monotonic() - t0 < seconds:
                i += 1
                phase = 2 * math.pi * i / 40
                frame = {
                    "type": "twist",
                    "source": "manual",
                    "linear_x": round(0.1 + 0.05 * math.sin(phase), 4),
                    "linear_y": 0.0,
                    "angular_z": round(0.3 * math.cos(phase), 4),
                }
                await ws.ws.send_json(frame)
                sent += 1
                await asyncio.sleep(max(0.0, t0 + i * 0.1 - time.monotonic()))
            out = cpu_phase(d.pid, t0, cpu0)
            out["twists_sent"] = sent
            out["states_received"] = ws.states
        finally:
            await ws.close()
    return out


async def run(spawns: int, phase_s: float) -> dict[str, Any]:
    ready_s: list[float] = []
    result: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="lupin-bench-") as tmp:
        home = Path(tmp)
        async with processes.simulator(home) as sim:
            for i in range(spawns):
                listener = NotifyListener(home / f"notify-{i}.sock")
                try:
                    env = {"NOTIFY_SOCKET": str(listener.path)}
                    async with processes.daemon(home, sim.path, env=env, name=f"daemon-{i}") as d:
                        ready_s.append(await listener.ready_at(30) - d.spawned_at)
                        if i == spawns - 1:
                            await asyncio.sleep(SETTLE_S)
                            result["idle"] = await idle(d, phase_s)
                            result["driving"] = await driving(d, phase_s)
                            result["peak_rss_kib"] = memory_kib(d.pid).get("VmHWM")
                finally:
                    await listener.close()
    return {
        "benchmark": NAME,
        "config": {
            **output.machine(),
            "profile": "so101",
            "tick_hz": 100,
            "spawns": spawns,
            "phase_s": phase_s,
        },
        "method": METHOD.replace("SPAWNS", str(spawns)),
        "start_to_ready_s": stats.summary(ready_s),
        "cpu": {
            "method": "daemon utime+stime / wall, 100 % = one core",
            "idle_percent": result["idle"]["cpu_percent"],
            "driving_percent": result["driving"]["cpu_percent"],
            "idle": result["idle"],
            "driving": result["driving"],
        },
        "memory": {
            "method": "VmRSS / VmHWM from /proc/PID/status, KiB",
            "rss_idle_kib": result["idle"]["rss_kib"],
            "rss_driving_kib": result["driving"]["rss_kib"],
            "peak_rss_kib": result["peak_rss_kib"],
        },
    }


def main(argv: Sequence[str] | None = None) -> int:
    p = output.parser(__doc__, NAME)
    p.add_argument("--spawns", type=int, default=5, help="start-to-READY measurements")
    p.add_argument("--seconds", type=float, default=10.0, help="per CPU phase")
    args = p.parse_args(argv)
    spawns, seconds = (1, 1.0) if args.smoke else (args.spawns, args.seconds)
    result = asyncio.run(run(spawns, seconds))
    output.emit(result, NAME, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
