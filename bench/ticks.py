"""Tick benchmark: the daemon as its own process, its tick read from ``/metrics``.

Prints one JSON document (and writes ``bench/results/ticks.json``):

* **quality at 100 Hz**: period jitter p50/p99/max and overruns, idle and while
  ``bench/load.py`` (a second process on loopback) runs 20 WebSocket clients
  streaming state and 200 HTTP requests per second;
* **rate sweep**: the daemon restarted with ``control.tick_hz`` 100, 200, 300, 400
  and 500 (a ``--config`` site file), overruns per rate, and the highest rate
  with none;
* **refresh**: full-state reads per second per servo at 100 Hz (every servo in
  every tick's SYNC_READ), against the seed's one arm joint per cycle.

The simulator is ``python -m lupin sim --wire-pacing`` (1 Mbaud, its own process);
the daemon is ``python -m lupin run --bus-port PTY --port 0 --pad none`` with
``LUPIN_AUTO_HOME=false`` and a temporary ``LUPIN_HOME``.

    python bench/ticks.py
    python bench/ticks.py --smoke
"""

from __future__ import annotations

import asyncio
import json
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import aiohttp
from benchlib import output, processes, prometheus
from benchlib.processes import DaemonProcess, cpu_seconds, memory_kib

from lupin.config import load_profile

NAME = "ticks"
LOAD = Path(__file__).resolve().parent / "load.py"
RATES = (100, 200, 300, 400, 500)
WARMUP_S = 1.0  # after ready: boot heal reads the bus once more

METHOD = (
    "Simulator (python -m lupin sim --wire-pacing, so101, 1 Mbaud) and daemon (python -m "
    "lupin run --bus-port PTY --port 0 --pad none, LUPIN_AUTO_HOME=false, temporary "
    "LUPIN_HOME, control.tick_hz from a --config site file) each in their own process on "
    "the 2-core machine. After ready and a 1 s warm-up, /metrics is scraped at the start "
    "and the end of a window of at least WINDOW ticks (2000, the control loop's jitter "
    "window, so lupin_tick_jitter_seconds quantiles cover exactly the last 2000 periods of "
    "the window and nothing before it). Jitter = |period - nominal| of tick starts "
    "(loop.time(), in the daemon); overruns, ticks, SYNC_READs and missed servo reads "
    "(timeout + truncated failures) are counter deltas; tick duration is the histogram's "
    "sum/count delta; daemon CPU % is utime+stime from /proc/PID/stat over the window "
    "(100 % = one core). Load: python bench/load.py in a third process (aiohttp, loopback) "
    "with 20 WebSocket clients receiving the 20 Hz state stream and 200 HTTP GET/s "
    "alternating /api/state and /api/health, at most 32 in flight; the window starts once "
    "every client is connected and the load is stopped (SIGTERM) when it ends."
)


async def measure(
    session: aiohttp.ClientSession, d: DaemonProcess, window_ticks: int, hz: float
) -> dict[str, Any]:
    """Scrape, let ``window_ticks`` ticks run, scrape again: the window's figures."""
    a = await prometheus.scrape(session, d.url)
    cpu0 = cpu_seconds(d.pid)
    start_ticks = a.get("lupin_ticks_total")
    cap = time.monotonic() + 4 * window_ticks / hz + 5
    b = a
    while b.get("lupin_ticks_total") - start_ticks < window_ticks and time.monotonic() < cap:
        missing = window_ticks - (b.get("lupin_ticks_total") - start_ticks)
        await asyncio.sleep(max(0.05, missing / hz))
        b = await prometheus.scrape(session, d.url)
    cpu = cpu_seconds(d.pid) - cpu0
    out = prometheus.window(a, b)
    out["daemon_cpu_percent"] = round(100 * cpu / (b.at - a.at), 2)
    out["daemon_rss_kib"] = memory_kib(d.pid).get("VmRSS")
    return out


async def under_load(
    session: aiohttp.ClientSession, d: DaemonProcess, window_ticks: int, load_args: list[str]
) -> dict[str, Any]:
    """``measure`` while bench/load.py hammers the API from another process."""
    duration = window_ticks / 100 + 15  # a bound only: it is stopped when the window ends
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        str(LOAD),
        d.url,
        *load_args,
        "--duration",
        f"{duration:g}",
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    try:
        assert proc.stdout is not None
        async with asyncio.timeout(30):
            started = json.loads(await proc.stdout.readline() or b"null")
        if not started or started.get("event") != "started":
            raise RuntimeError(f"load.py did not start: {started!r}")
        window = await measure(session, d, window_ticks, 100)
        await processes.terminate(proc, grace=10)
        out, err = await proc.communicate()
        lines = out.decode().strip().splitlines()
        if not lines:
            raise RuntimeError(f"load.py printed no summary: {err.decode()[-2000:]}")
        window["load"] = json.loads(lines[-1])
        return window
    finally:
        if proc.returncode is None:
            await processes.terminate(proc, grace=2)


async def run(rates: Sequence[int], window_ticks: int, load_args: list[str]) -> dict[str, Any]:
    sweep: dict[str, Any] = {}
    quality: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="lupin-bench-") as tmp:
        home = Path(tmp)
        profile = load_profile("so101", home=home)
        servos = len(profile.arm.joints) + (len(profile.base.wheels) if profile.base else 0)
        async with processes.simulator(home) as sim, aiohttp.ClientSession() as session:
            for hz in rates:
                config = processes.site_config(home, hz)
                async with processes.daemon(
                    home, sim.path, config=config, name=f"daemon-{hz}hz"
                ) as d:
                    await asyncio.sleep(WARMUP_S)
                    idle = await measure(session, d, window_ticks, hz)
                    sweep[str(hz)] = idle
                    if hz == 100:
                        quality["idle"] = idle
                        quality["load"] = await under_load(session, d, window_ticks, load_args)
    return report(sweep, quality, servos, window_ticks, load_args)


def refresh(idle: dict[str, Any], servos: int) -> dict[str, Any]:
    """Full-state reads per second per servo, from one window's counters."""
    reads = idle["sync_reads"] * servos - idle["servo_reads_missed"]
    per_servo = reads / servos / idle["wall_s"]
    return {
        "method": "(SYNC_READs x servos - missed servo reads) / servos / window wall time, "
        "from lupin_bus_transactions_total{kind=sync_read} and lupin_bus_failures_total "
        "deltas in the 100 Hz idle window; every SYNC_READ asks every servo for position, "
        "speed and load",
        "servos": servos,
        "ticks_per_s": idle["ticks_per_s"],
        "full_state_reads_per_s_per_servo": round(per_servo, 2),
        "servo_reads_missed": idle["servo_reads_missed"],
    }


def report(
    sweep: dict[str, Any],
    quality: dict[str, Any],
    servos: int,
    window_ticks: int,
    load_args: list[str],
) -> dict[str, Any]:
    clean = [int(hz) for hz, w in sweep.items() if w["overruns"] == 0]
    nearly = [int(hz) for hz, w in sweep.items() if (w["overrun_fraction"] or 0) < 0.01]
    rates = {
        hz: {k: w[k] for k in ("ticks_per_s", "overruns", "overrun_fraction", "jitter_ms")}
        | {
            "tick_duration_mean_ms": w["tick_duration_mean_ms"],
            "cpu_percent": w["daemon_cpu_percent"],
        }
        for hz, w in sweep.items()
    }
    return {
        "benchmark": NAME,
        "config": {
            **output.machine(),
            "profile": "so101",
            "window_ticks": window_ticks,
            "rates_hz": [int(hz) for hz in sweep],
            "load": " ".join(load_args),
            "wire_pacing": True,
        },
        "method": METHOD.replace("WINDOW", str(window_ticks)),
        "quality_100hz": {
            "method": "jitter and overruns at control.tick_hz 100, idle then under load",
            **quality,
        },
        "sweep": {
            "method": "one daemon per rate, idle; overruns = ticks that ended past their slot "
            "(ControlLoop.run), so the next tick starts late (no catch-up burst); "
            "highest_without_overrun_hz = the highest rate whose window had none; "
            "highest_under_1pct_overruns_hz = the highest with fewer than 1 % of ticks "
            "overrun; durations_over_nominal counts ticks that were themselves longer than "
            "a period (the rest of the overruns are late wake-ups)",
            "highest_without_overrun_hz": max(clean, default=None),
            "highest_under_1pct_overruns_hz": max(nearly, default=None),
            "rates": rates,
            "windows": sweep,
        },
        "refresh": refresh(quality["idle"], servos) if "idle" in quality else None,
    }


def main(argv: Sequence[str] | None = None) -> int:
    p = output.parser(__doc__, NAME)
    p.add_argument("--window-ticks", type=int, default=prometheus.SUMMARY_WINDOW)
    args = p.parse_args(argv)
    if args.smoke:
        rates: Sequence[int] = (100, 200)
        window = 40
        load_args = ["--ws-clients", "2", "--rps", "20"]
    else:
        rates, window = RATES, args.window_ticks
        load_args = ["--ws-clients", "20", "--rps", "200"]
    result = asyncio.run(run(rates, window, load_args))
    output.emit(result, NAME, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
