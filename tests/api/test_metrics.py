"""``/metrics``: well-formed Prometheus text with the tick, bus, mux and WebSocket families."""

from __future__ import annotations

import asyncio
import math
import re

import aiohttp

from lupin.api import ApiServer
from lupin.api.metrics import Histogram, Metrics, quantile
from lupin.daemon import Daemon

from .helpers import call

SAMPLE = re.compile(r'^([a-z_:][a-z0-9_:]*)(\{([a-z_]+="(?:[^"\\]|\\.)*",?)*\})? (\S+)$')


def parse(text: str) -> dict[str, float]:
    """``name{labels}`` -> value; asserts every line is a comment or a valid sample."""
    samples: dict[str, float] = {}
    types: dict[str, str] = {}
    for line in text.splitlines():
        if line.startswith("# TYPE "):
            _, _, name, kind = line.split(" ")
            types[name] = kind
            continue
        if line.startswith("# HELP ") or not line:
            continue
        match = SAMPLE.match(line)
        assert match, f"not a Prometheus sample: {line!r}"
        key = line.rsplit(" ", 1)[0]
        assert key not in samples, f"duplicate sample {key}"
        samples[key] = float(line.rsplit(" ", 1)[1])
        base = re.sub(r"_(bucket|sum|count)$", "", match.group(1))
        assert match.group(1) in types or base in types, f"sample without TYPE: {line}"
    return samples


async def scrape(http: aiohttp.ClientSession, api: ApiServer) -> dict[str, float]:
    async with http.get(api.url + "/metrics") as resp:
        assert resp.status == 200
        assert resp.headers["Content-Type"].startswith("text/plain; version=0.0.4")
        return parse(await resp.text())


def test_histogram_is_cumulative() -> None:
    h = Histogram([0.01, 0.02])
    for v in (0.005, 0.015, 0.5):
        h.observe(v)
    assert h.lines("x") == [
        'x_bucket{le="0.01"} 1',
        'x_bucket{le="0.02"} 2',
        'x_bucket{le="+Inf"} 3',
        "x_sum 0.52",
        "x_count 3",
    ]


def test_quantile_nearest_rank() -> None:
    assert quantile([1.0, 2.0, 3.0, 4.0], 0.5) == 2.0
    assert quantile([1.0, 2.0, 3.0, 4.0], 1.0) == 4.0
    assert math.isnan(quantile([], 0.5))


def test_only_new_periods_are_counted_between_scrapes() -> None:
    metrics = Metrics(tick_hz=100.0)
    telemetry = {"ticks": 3, "tick_periods": [0.01, 0.011, 0.009], "tick_durations": []}
    metrics.render(telemetry, 0, 0)
    assert metrics.periods.count == 3
    telemetry = {"ticks": 5, "tick_periods": [0.01, 0.011, 0.009, 0.01, 0.03], "tick_durations": []}
    metrics.render(telemetry, 0, 0)
    assert metrics.periods.count == 5 and metrics.periods.sum == sum(telemetry["tick_periods"])


async def test_metrics_families(
    http: aiohttp.ClientSession, api: ApiServer, daemon: Daemon
) -> None:
    await asyncio.sleep(0.3)  # a few dozen ticks
    async with http.ws_connect(api.url + "/api/ws") as ws:
        await ws.receive_json(timeout=2)
        await call(http, api, "POST", "/api/base/twist", {"source": "manual", "linear_x": 0.1})
        first = await scrape(http, api)
    assert first["lupin_websocket_clients"] == 1
    assert first['lupin_mux_active{source="manual"}'] == 1
    assert first['lupin_mux_active{source="joy"}'] == 0
    assert first["lupin_estop_engaged"] == 0
    assert first["lupin_ticks_total"] > 10
    assert first['lupin_tick_period_seconds_bucket{le="+Inf"}'] > 10
    assert (
        first["lupin_tick_period_seconds_count"]
        == first['lupin_tick_period_seconds_bucket{le="+Inf"}']
    )
    jitter = [first[f'lupin_tick_jitter_seconds{{quantile="{q}"}}'] for q in (0.5, 0.9, 0.99, 1.0)]
    assert 0 <= jitter[0] <= jitter[1] <= jitter[2] <= jitter[3] < 1.0
    assert first['lupin_bus_transactions_total{kind="sync_read"}'] > 10
    assert "lupin_tick_overruns_total" in first
    await asyncio.sleep(0.2)
    await call(http, api, "POST", "/api/estop", {"engaged": True})
    second = await scrape(http, api)
    assert second["lupin_estop_engaged"] == 1
    assert second["lupin_websocket_clients"] == 0
    # Counters only go up.
    for key, value in first.items():
        if key.endswith(("_total", "_count")) or "_bucket{" in key:
            assert second.get(key, value) >= value, key
    assert second["lupin_tick_period_seconds_count"] > first["lupin_tick_period_seconds_count"]


async def test_bus_failures_are_labelled_by_kind(
    http: aiohttp.ClientSession, api: ApiServer, daemon: Daemon
) -> None:
    assert daemon.bus is not None
    daemon.bus.stats.fail("timeout", 3)
    samples = await scrape(http, api)
    assert samples['lupin_bus_failures_total{kind="timeout"}'] >= 3
