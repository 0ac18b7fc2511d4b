"""``/metrics``: the Prometheus text exposition format, written by hand (it is simple).

What is exported and why:
* ``lupin_tick_period_seconds`` histogram: time between tick starts, buckets
  as multiples of the nominal period, so jitter shows up as spread around 1x;
* ``lupin_tick_jitter_seconds`` summary: quantiles of |period - nominal| over
  the recent window the control loop keeps (Prometheus summaries are windowed);
* ``lupin_tick_duration_seconds`` histogram, ticks and overruns counters;
* bus transactions and failures by kind, mux active source (one 0/1 gauge per
  source), E-stop, WebSocket clients and state frames dropped for slow clients.

The service layer hands over the recent tick periods (a bounded window) and
the tick count; the histograms take only the periods not seen at the previous
scrape, so they stay cumulative as Prometheus expects.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"
PERIOD_MULTIPLES = (0.5, 0.8, 0.9, 0.95, 0.98, 1.02, 1.05, 1.1, 1.2, 1.5, 2.0, 3.0, 5.0)
DURATION_MULTIPLES = (0.05, 0.1, 0.2, 0.3, 0.5, 0.75, 1.0, 1.5, 2.0)
QUANTILES = (0.5, 0.9, 0.99, 1.0)


def _num(value: float) -> str:
    if math.isinf(value):
        return "+Inf" if value > 0 else "-Inf"
    if math.isnan(value):
        return "NaN"
    return repr(float(value)) if not float(value).is_integer() else str(int(value))


def _bound(value: float) -> float:
    """A bucket bound that prints short (0.009, not 0.009000000000000001)."""
    return float(f"{value:.6g}")


def _label(value: object) -> str:
    text = str(value).replace("\\", "\\\\").replace("\n", "\\n").replace('"', '\\"')
    return f'"{text}"'


class Histogram:
    def __init__(self, bounds: Sequence[float]) -> None:
        self.bounds = tuple(sorted(bounds))
        self.buckets = [0] * len(self.bounds)
        self.count = 0
        self.sum = 0.0

    def observe(self, value: float) -> None:
        self.count += 1
        self.sum += value
        for i, bound in enumerate(self.bounds):
            if value <= bound:
                self.buckets[i] += 1

    def lines(self, name: str) -> list[str]:
        pairs = zip(self.bounds, self.buckets, strict=True)
        out = [f"{name}_bucket{{le={_label(_num(b))}}} {n}" for b, n in pairs]
        out.append(f'{name}_bucket{{le="+Inf"}} {self.count}')
        out.append(f"{name}_sum {_num(self.sum)}")
        out.append(f"{name}_count {self.count}")
        return out


def quantile(sorted_values: Sequence[float], q: float) -> float:
    """Nearest-rank quantile of an already sorted sequence (NaN when empty)."""
    if not sorted_values:
        return math.nan
    rank = max(1, math.ceil(q * len(sorted_values)))
    return sorted_values[min(rank, len(sorted_values)) - 1]


class Metrics:
    """Cumulative state between scrapes, and the rendering of one scrape."""

    def __init__(self, tick_hz: float) -> None:
        self.nominal = 1.0 / tick_hz
        self.periods = Histogram([_bound(m * self.nominal) for m in PERIOD_MULTIPLES])
        self.durations = Histogram([_bound(m * self.nominal) for m in DURATION_MULTIPLES])
        self.jitter_sum = 0.0
        self.jitter_count = 0
        self._seen_ticks: int | None = None

    def _take_new(self, ticks: int, periods: Sequence[float], durations: Sequence[float]) -> None:
        new = ticks if self._seen_ticks is None else ticks - self._seen_ticks
        self._seen_ticks = ticks
        if new <= 0:
            return
        for value in periods[-new:]:
            self.periods.observe(value)
            self.jitter_sum += abs(value - self.nominal)
            self.jitter_count += 1
        for value in durations[-new:]:
            self.durations.observe(value)

    def render(self, telemetry: Mapping[str, Any], ws_clients: int, ws_replaced: int) -> str:
        periods: list[float] = list(telemetry.get("tick_periods", []))
        durations: list[float] = list(telemetry.get("tick_durations", []))
        self._take_new(int(telemetry.get("ticks", 0)), periods, durations)
        jitter = sorted(abs(p - self.nominal) for p in periods)
        out: list[str] = []

        def metric(name: str, kind: str, help_text: str, lines: Iterable[str]) -> None:
            out.append(f"# HELP {name} {help_text}")
            out.append(f"# TYPE {name} {kind}")
            out.extend(lines)

        metric(
            "lupin_tick_period_seconds",
            "histogram",
            "Time between control tick starts.",
            self.periods.lines("lupin_tick_period_seconds"),
        )
        metric(
            "lupin_tick_jitter_seconds",
            "summary",
            "Absolute deviation of the tick period from nominal, over the recent window.",
            [
                *(
                    f"lupin_tick_jitter_seconds{{quantile={_label(q)}}} {_num(quantile(jitter, q))}"
                    for q in QUANTILES
                ),
                f"lupin_tick_jitter_seconds_sum {_num(self.jitter_sum)}",
                f"lupin_tick_jitter_seconds_count {self.jitter_count}",
            ],
        )
        metric(
            "lupin_tick_duration_seconds",
            "histogram",
            "Time spent inside one control tick.",
            self.durations.lines("lupin_tick_duration_seconds"),
        )
        metric(
            "lupin_tick_nominal_period_seconds",
            "gauge",
            "The configured tick period.",
            [f"lupin_tick_nominal_period_seconds {_num(self.nominal)}"],
        )
        metric(
            "lupin_ticks_total",
            "counter",
            "Control ticks run.",
            [f"lupin_ticks_total {int(telemetry.get('ticks', 0))}"],
        )
        metric(
            "lupin_tick_overruns_total",
            "counter",
            "Ticks that ran past their slot.",
            [f"lupin_tick_overruns_total {int(telemetry.get('tick_overruns', 0))}"],
        )
        metric(
            "lupin_bus_transactions_total",
            "counter",
            "Servo bus transactions by kind.",
            [
                f"lupin_bus_transactions_total{{kind={_label(k)}}} {int(v)}"
                for k, v in sorted(telemetry.get("bus_transactions", {}).items())
            ],
        )
        metric(
            "lupin_bus_failures_total",
            "counter",
            "Servo bus failures by kind.",
            [
                f"lupin_bus_failures_total{{kind={_label(k)}}} {int(v)}"
                for k, v in sorted(telemetry.get("bus_failures", {}).items())
            ],
        )
        active = telemetry.get("mux_active")
        sources = list(telemetry.get("mux_sources", []))
        if active is not None and active not in sources:
            sources.append(active)
        metric(
            "lupin_mux_active",
            "gauge",
            "1 for the velocity mux source now driving the base.",
            [f"lupin_mux_active{{source={_label(s)}}} {int(s == active)}" for s in sources],
        )
        metric(
            "lupin_estop_engaged",
            "gauge",
            "1 while the E-stop is engaged.",
            [f"lupin_estop_engaged {int(bool(telemetry.get('estop')))}"],
        )
        metric(
            "lupin_websocket_clients",
            "gauge",
            "Connected WebSocket clients.",
            [f"lupin_websocket_clients {ws_clients}"],
        )
        metric(
            "lupin_websocket_states_dropped_total",
            "counter",
            "State frames replaced unsent because a client was slower than the push rate.",
            [f"lupin_websocket_states_dropped_total {ws_replaced}"],
        )
        return "\n".join(out) + "\n"
