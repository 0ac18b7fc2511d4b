"""Read the daemon's ``/metrics`` and turn two scrapes into the figures of one window.

What the daemon exports (``lupin/api/metrics.py``) and how it is used here:

* ``lupin_ticks_total``, ``lupin_tick_overruns_total``: counters, taken as deltas;
* ``lupin_tick_jitter_seconds{quantile}``: |period - nominal| over the control
  loop's recent window of 2000 periods; a window is only reported from it when
  at least 2000 ticks ran between the two scrapes, so the quantiles cover this
  window and nothing before it (``jitter_from_summary``);
* ``lupin_tick_period_seconds`` and ``lupin_tick_duration_seconds`` histograms:
  cumulative, taken as bucket deltas (coarse: bounds at multiples of the period);
* ``lupin_bus_transactions_total{kind}``, ``lupin_bus_failures_total{kind}``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import aiohttp

SUMMARY_WINDOW = 2000  # TickStats.periods maxlen in lupin/control_loop.py


def parse(text: str) -> dict[str, float]:
    """Samples by their full name as written (``name{label="v"}``)."""
    out: dict[str, float] = {}
    for line in text.splitlines():
        if not line or line.startswith("#"):
            continue
        name, _, value = line.rpartition(" ")
        out[name] = float(value)
    return out


@dataclass
class Scrape:
    at: float  # time.monotonic() of the scrape
    samples: dict[str, float]

    def get(self, name: str, default: float = 0.0) -> float:
        return self.samples.get(name, default)

    def buckets(self, name: str) -> list[tuple[float, float]]:
        """(upper bound, cumulative count) of a histogram, +Inf last."""
        prefix = f'{name}_bucket{{le="'
        out = []
        for key, value in self.samples.items():
            if key.startswith(prefix):
                bound = key[len(prefix) : -2]
                out.append((math.inf if bound == "+Inf" else float(bound), value))
        return sorted(out)


async def scrape(session: aiohttp.ClientSession, url: str) -> Scrape:
    async with session.get(f"{url}/metrics") as response:
        response.raise_for_status()
        text = await response.text()
    return Scrape(time.monotonic(), parse(text))


def window(a: Scrape, b: Scrape) -> dict[str, Any]:
    """The tick figures between two scrapes of one daemon."""
    wall = b.at - a.at
    nominal = b.get("lupin_tick_nominal_period_seconds")
    ticks = b.get("lupin_ticks_total") - a.get("lupin_ticks_total")
    overruns = b.get("lupin_tick_overruns_total") - a.get("lupin_tick_overruns_total")
    sync_reads = b.get('lupin_bus_transactions_total{kind="sync_read"}') - a.get(
        'lupin_bus_transactions_total{kind="sync_read"}'
    )
    missed = sum(
        b.get(f'lupin_bus_failures_total{{kind="{k}"}}')
        - a.get(f'lupin_bus_failures_total{{kind="{k}"}}')
        for k in ("timeout", "truncated")
    )
    full = ticks >= SUMMARY_WINDOW
    jitter = {
        key: b.get(f'lupin_tick_jitter_seconds{{quantile="{q}"}}') * 1000
        for key, q in (("p50", 0.5), ("p90", 0.9), ("p99", 0.99), ("max", 1.0))
    }
    dur_n = b.get("lupin_tick_duration_seconds_count") - a.get("lupin_tick_duration_seconds_count")
    dur_sum = b.get("lupin_tick_duration_seconds_sum") - a.get("lupin_tick_duration_seconds_sum")
    periods = _bucket_delta(a, b, "lupin_tick_period_seconds")
    durations = _bucket_delta(a, b, "lupin_tick_duration_seconds")
    return {
        "wall_s": round(wall, 3),
        "nominal_hz": round(1 / nominal, 3) if nominal else None,
        "ticks": int(ticks),
        "ticks_per_s": round(ticks / wall, 2) if wall > 0 else None,
        "overruns": int(overruns),
        "overrun_fraction": round(overruns / ticks, 5) if ticks else None,
        "jitter_ms": {k: round(v, 3) for k, v in jitter.items()},
        "jitter_from_summary": "this window only" if full else "includes ticks before it",
        "periods_over_1_5x_nominal": int(_count_above(periods, 1.5 * nominal)),
        "tick_duration_mean_ms": round(1000 * dur_sum / dur_n, 3) if dur_n else None,
        "durations_over_half_nominal": int(_count_above(durations, 0.5 * nominal)),
        "durations_over_nominal": int(_count_above(durations, nominal)),
        "sync_reads": int(sync_reads),
        "servo_reads_missed": int(missed),
    }


def _bucket_delta(a: Scrape, b: Scrape, name: str) -> list[tuple[float, float]]:
    before = dict(a.buckets(name))
    return [(bound, n - before.get(bound, 0.0)) for bound, n in b.buckets(name)]


def _count_above(cumulative: list[tuple[float, float]], threshold: float) -> float:
    """Observations above the bucket bound at ``threshold`` (bounds print to 6 digits)."""
    total = cumulative[-1][1] if cumulative else 0.0
    limit = threshold * (1 + 1e-5)
    below = max((n for bound, n in cumulative if bound <= limit), default=0.0)
    return total - below
