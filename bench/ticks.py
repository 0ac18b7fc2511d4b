"""Tick benchmark: the daemon as its own process, its tick read from ``/metrics``.

Prints one JSON document (and writes ``bench/results/ticks.json``):

* **quality at 100 Hz**: period jitter p50/p99/max and overruns, idle and while
  ``bench/load.py`` (a second process on loopback) runs 20 WebSocket clients
  streaming state and 200 HTTP requests per second, in alternating windows
  (idle, load, idle, load) pooled per condition, so drift in the machine's load
  or the daemon's warm-up falls on both conditions alike;
* **rate sweep**: the daemon restarted with ``control.tick_hz`` 100, 200, 300 and
  400 (a ``--config`` site file), then bisected down to 25 Hz steps where it
  matters, overruns per rate, and the highest rate sustained with none (and
  with under 1 %): the highest that passed *with every lower swept rate*;
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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import aiohttp
from benchlib import output, processes, prometheus
from benchlib.processes import DaemonProcess, cpu_seconds, memory_kib

from lupin.config import load_profile

NAME = "ticks"
LOAD = Path(__file__).resolve().parent / "load.py"
COARSE_RATES = (100, 200, 300, 400)  # 400 Hz ran 42 % overruns on 2 cores: no need for more
RESOLUTION_HZ = 25  # bisect until the passing and failing rates are this close
QUALITY_HZ = 100
ROUNDS = 2  # idle/load window pairs at 100 Hz: one of each is noise, not a comparison
WARMUP_S = 1.0  # after ready: boot heal reads the bus once more
SETTLE_S = 1.0  # after the load stops: its 20 clients' disconnects are not idle
UNDER = 0.01  # the second figure: fewer than 1 % of ticks overrun
QUANTILES = ("p50", "p90", "p99")  # of lupin_tick_jitter_seconds, besides the max
Window = dict[str, Any]


@dataclass(frozen=True)
class Plan:
    """What one run sweeps and how long each window is."""

    coarse_hz: Sequence[int]  # always swept; 100 Hz (the quality windows) is added if missing
    resolution_hz: int
    window_ticks: int
    rounds: int  # idle/load window pairs at 100 Hz
    load_args: list[str]


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
    "every client is connected and the load is stopped (SIGTERM) when it ends. At 100 Hz, "
    "ROUNDS idle and ROUNDS load windows alternate in one daemon (idle, load, idle, load; "
    "1 s after each load before the next idle window) and each condition pools its "
    "windows: counts summed, ticks/s and CPU % over the summed wall time, jitter "
    "p50/p90/p99 the tick-weighted mean of the windows' quantiles (the daemon exports "
    "quantiles, not periods; the exact pooled quantile lies between the windows' lowest "
    "and highest, all in jitter_ms_by_window) and max the largest."
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


async def quality(
    session: aiohttp.ClientSession,
    d: DaemonProcess,
    window_ticks: int,
    rounds: int,
    load_args: list[str],
) -> dict[str, Window]:
    """Idle and loaded windows in turn, pooled per condition.

    One window of each, back to back, compared the machine's noise more than the
    conditions (idle once came out worse than loaded); alternating them spreads
    whatever drifts over both.
    """
    idle: list[Window] = []
    load: list[Window] = []
    for _ in range(rounds):
        if load:
            await asyncio.sleep(SETTLE_S)
        idle.append(await measure(session, d, window_ticks, QUALITY_HZ))
        load.append(await under_load(session, d, window_ticks, load_args))
    return {"idle": pool(idle), "load": pool(load)}


def pool(windows: Sequence[Window]) -> Window:
    """One condition's figures over several windows of one daemon (see METHOD for the rules)."""
    ticks = sum(w["ticks"] for w in windows)
    wall = sum(w["wall_s"] for w in windows)
    summed = (
        "overruns",
        "sync_reads",
        "servo_reads_missed",
        "periods_over_1_5x_nominal",
        "durations_over_half_nominal",
        "durations_over_nominal",
    )
    out: Window = {k: sum(w[k] for w in windows) for k in summed}
    jitter = {q: _tick_mean(windows, [w["jitter_ms"][q] for w in windows]) for q in QUANTILES}
    jitter["max"] = max(w["jitter_ms"]["max"] for w in windows)
    only_this = all(w["jitter_from_summary"] == "this window only" for w in windows)
    return out | {
        "windows": len(windows),
        "wall_s": round(wall, 3),
        "nominal_hz": windows[0]["nominal_hz"],
        "ticks": ticks,
        "ticks_per_s": round(ticks / wall, 2) if wall > 0 else None,
        "overrun_fraction": round(out["overruns"] / ticks, 5) if ticks else None,
        "jitter_ms": jitter,
        "jitter_ms_by_window": [w["jitter_ms"] for w in windows],
        "jitter_from_summary": "each window only" if only_this else "includes ticks before",
        "tick_duration_mean_ms": _tick_mean(windows, [w["tick_duration_mean_ms"] for w in windows]),
        "daemon_cpu_percent": round(
            sum(w["daemon_cpu_percent"] * w["wall_s"] for w in windows) / wall, 2
        ),
        "daemon_rss_kib": max((w["daemon_rss_kib"] or 0) for w in windows) or None,
        "by_window": list(windows),
    }


def _tick_mean(windows: Sequence[Window], values: Sequence[float | None]) -> float | None:
    """The mean of one figure per window, weighted by each window's ticks (None: skipped)."""
    pairs = [(v, w["ticks"]) for v, w in zip(values, windows, strict=True) if v is not None]
    n = sum(t for _, t in pairs)
    return round(sum(v * t for v, t in pairs) / n, 3) if n else None


def clean(w: Window) -> bool:
    """The window ran and no tick overran."""
    return bool(w["ticks"]) and w["overruns"] == 0


def nearly_clean(w: Window) -> bool:
    """The window ran and fewer than 1 % of its ticks overran."""
    return bool(w["ticks"]) and w["overruns"] < UNDER * w["ticks"]


def verdicts(sweep: Mapping[int, Window], passes: Callable[[Window], bool]) -> dict[int, bool]:
    """Rate -> whether its window passed ``passes``."""
    return {hz: passes(w) for hz, w in sweep.items()}


def highest_sustained(passed: Mapping[int, bool]) -> int | None:
    """The highest swept rate that passed, every lower swept rate having passed too.

    A rate that passes above one that failed had a quiet window, not headroom:
    the daemon cannot be said to sustain 300 Hz when it overran at 200 Hz. None
    when even the lowest failed (or nothing was swept).
    """
    best = None
    for hz in sorted(passed):
        if not passed[hz]:
            break
        best = hz
    return best


def next_probe(passed: Mapping[int, bool], resolution_hz: int = RESOLUTION_HZ) -> int | None:
    """The rate halfway between the highest sustained one and the next swept rate above it.

    None when the answer is already that precise: no rate above was swept, even the
    lowest failed, or the two are at most ``resolution_hz`` apart.
    """
    best = highest_sustained(passed)
    above = [hz for hz in passed if best is not None and hz > best]
    if best is None or not above or min(above) - best <= resolution_hz:
        return None
    return (best + min(above)) // 2


async def run(plan: Plan) -> dict[str, Any]:
    sweep: dict[int, Window] = {}
    quality_windows: dict[str, Window] = {}
    with tempfile.TemporaryDirectory(prefix="lupin-bench-") as tmp:
        home = Path(tmp)
        profile = load_profile("so101", home=home)
        servos = len(profile.arm.joints) + (len(profile.base.wheels) if profile.base else 0)
        async with processes.simulator(home) as sim, aiohttp.ClientSession() as session:

            async def at(hz: int) -> Window:
                """One daemon at ``hz``: its idle window (at 100 Hz, the pooled idle windows)."""
                config = processes.site_config(home, hz)
                async with processes.daemon(
                    home, sim.path, config=config, name=f"daemon-{hz}hz"
                ) as d:
                    await asyncio.sleep(WARMUP_S)
                    if hz != QUALITY_HZ:
                        return await measure(session, d, plan.window_ticks, hz)
                    quality_windows.update(
                        await quality(session, d, plan.window_ticks, plan.rounds, plan.load_args)
                    )
                    return quality_windows["idle"]

            for hz in sorted({QUALITY_HZ, *plan.coarse_hz}):
                sweep[hz] = await at(hz)
            for passes in (clean, nearly_clean):
                while (
                    probe := next_probe(verdicts(sweep, passes), plan.resolution_hz)
                ) is not None:
                    sweep[probe] = await at(probe)
    return report(dict(sorted(sweep.items())), quality_windows, servos, plan)


def refresh(idle: dict[str, Any], servos: int) -> dict[str, Any]:
    """Full-state reads per second per servo, from one condition's counters."""
    reads = idle["sync_reads"] * servos - idle["servo_reads_missed"]
    per_servo = reads / servos / idle["wall_s"]
    return {
        "method": "(SYNC_READs x servos - missed servo reads) / servos / window wall time, "
        "from lupin_bus_transactions_total{kind=sync_read} and lupin_bus_failures_total "
        "deltas over the 100 Hz idle windows; every SYNC_READ asks every servo for position, "
        "speed and load",
        "servos": servos,
        "ticks_per_s": idle["ticks_per_s"],
        "full_state_reads_per_s_per_servo": round(per_servo, 2),
        "servo_reads_missed": idle["servo_reads_missed"],
    }


def report(
    sweep: dict[int, Window], quality_windows: dict[str, Window], servos: int, plan: Plan
) -> dict[str, Any]:
    rates = {
        str(hz): {k: w[k] for k in ("ticks_per_s", "overruns", "overrun_fraction", "jitter_ms")}
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
            "window_ticks": plan.window_ticks,
            "quality_rounds": plan.rounds,
            "coarse_rates_hz": list(plan.coarse_hz),
            "resolution_hz": plan.resolution_hz,
            "rates_hz": list(sweep),
            "load": " ".join(plan.load_args),
            "wire_pacing": True,
        },
        "method": METHOD.replace("WINDOW", str(plan.window_ticks)).replace(
            "ROUNDS", str(plan.rounds)
        ),
        "quality_100hz": {
            "method": f"jitter and overruns at control.tick_hz 100: {plan.rounds} idle and "
            f"{plan.rounds} loaded windows, alternating, each condition pooled over its windows",
            **quality_windows,
        },
        "sweep": {
            "method": "one daemon per rate, idle; the coarse rates, then for each figure the "
            "rate halfway between the highest sustained and the next swept rate above it, "
            f"until the two are at most {plan.resolution_hz} Hz apart; "
            "overruns = ticks that ended past their slot (ControlLoop.run), so the next tick "
            "starts late (no catch-up burst); highest_without_overrun_hz = the highest swept "
            "rate whose window had no overrun and neither had any lower swept rate; "
            "highest_under_1pct_overruns_hz = the same with fewer than 1 % of ticks overrun; "
            "the 100 Hz entry pools the idle windows above; durations_over_nominal counts "
            "ticks that were themselves longer than a period (the rest of the overruns are "
            "late wake-ups)",
            "highest_without_overrun_hz": highest_sustained(verdicts(sweep, clean)),
            "highest_under_1pct_overruns_hz": highest_sustained(verdicts(sweep, nearly_clean)),
            "rates": rates,
            "windows": {str(hz): w for hz, w in sweep.items()},
        },
        "refresh": refresh(quality_windows["idle"], servos) if "idle" in quality_windows else None,
    }


def main(argv: Sequence[str] | None = None) -> int:
    p = output.parser(__doc__, NAME)
    p.add_argument("--window-ticks", type=int, default=prometheus.SUMMARY_WINDOW)
    p.add_argument("--rounds", type=int, default=ROUNDS, help="idle/load window pairs at 100 Hz")
    args = p.parse_args(argv)
    if args.rounds < 1 or args.window_ticks < 1:
        p.error("--rounds and --window-ticks must be at least 1")
    if args.smoke:  # at most one probe per figure (150 Hz)
        plan = Plan((100, 200), 50, 40, args.rounds, ["--ws-clients", "2", "--rps", "20"])
    else:
        load_args = ["--ws-clients", "20", "--rps", "200"]
        plan = Plan(COARSE_RATES, RESOLUTION_HZ, args.window_ticks, args.rounds, load_args)
    result = asyncio.run(run(plan))
    output.emit(result, NAME, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
