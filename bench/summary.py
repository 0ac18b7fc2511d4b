"""The headline table of a ``run_all`` document: one row per measurement, with its baseline.

Each row is ``{measure, lupin, baseline, baseline_kind, method}``. ``baseline_kind``
says what the right-hand column is: ``measured`` (the same run, e.g. the vendor
SDK), ``computed`` (arithmetic from the protocol, e.g. packet sizes from the
codec: exact, but nothing was timed or counted), ``reference`` (a number the
seeds document for the ROS graph; not measured), or ``target`` (what the
specification asks for).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

Row = dict[str, str]


def _ms(s: dict[str, Any], *keys: str) -> str:
    return " / ".join(f"{s[k]:.1f}" for k in keys) + " ms"


def _one_tick(s: dict[str, Any]) -> str:
    """Both readings of the "one tick" target, so neither passes for the other.

    "On the next tick's write" counts tick starts between stimulus and goal, and
    such a goal can land a little over one period later; the share under one
    period is the millisecond reading. The percentage is floored: 199/200 is not 100 %.
    """
    n = s["latency_ms"]["n"]
    under = s["under_one_period"]
    share = math.floor(100 * under / n) if n else 0
    return (
        f"{s['next_tick_write']}/{n} on the next tick's write; "
        f"{under}/{n} ({share} %) under {s['period_ms']:g} ms"
    )


def _row(measure: str, lupin: str, baseline: str, kind: str, method: str) -> Row:
    return {
        "measure": measure,
        "lupin": lupin,
        "baseline": baseline,
        "baseline_kind": kind,
        "method": method,
    }


def latency_rows(doc: dict[str, Any]) -> list[Row]:
    rows = []
    period_ms = 1000 / doc["config"]["tick_hz"]
    for key, measure in (
        ("stop", "Stop: dead-man release → wheels at 0 (p50 / p99 / max)"),
        ("estop_http", "E-stop via HTTP POST → wheels at 0 (p50 / p99 / max)"),
        ("estop_ws", "E-stop via WebSocket → wheels at 0 (p50 / p99 / max)"),
    ):
        s = doc[key]
        rows.append(
            _row(
                measure,
                f"{_ms(s['latency_ms'], 'p50', 'p99', 'max')}; {_one_tick(s)}",
                f"one tick ({period_ms:g} ms)",
                "target",
                s["method"] + " (in-process sim, same clock)",
            )
        )
    t = doc["teleop"]
    rows.append(
        _row(
            "Teleop: stick change (LB held) → goal speed at servos (p50 / p99)",
            f"{_ms(t['latency_ms'], 'p50', 'p99')}; {_one_tick(t)}",
            f"one tick ({period_ms:g} ms)",
            "target",
            t["method"],
        )
    )
    wire = doc["wire"]
    rows.append(
        _row(
            "Bus bytes per tick at 1 Mbaud (idle / driving, measured)",
            f"{wire['idle']['bytes_per_tick']:.0f} / {wire['driving']['bytes_per_tick']:.0f} B = "
            f"{100 * wire['idle']['utilisation_fraction_at_tick_hz']:.1f} / "
            f"{100 * wire['driving']['utilisation_fraction_at_tick_hz']:.1f} % of the wire "
            "at 100 Hz",
            f"codec: {wire['codec']['idle_bytes_per_tick']:.0f} B idle, "
            f"{wire['codec']['busiest_bytes_per_tick']:.0f} B worst case",
            "computed",
            "daemon's own bus byte counters / ticks; the baseline is packet sizes from the "
            "codec (arithmetic, not a measurement)",
        )
    )
    return rows


def tick_rows(doc: dict[str, Any]) -> list[Row]:
    rows = []
    q, config = doc["quality_100hz"], doc["config"]
    window = f"{config['window_ticks']}-tick windows"
    pooled = f"{config['quality_rounds']} {window} per condition, idle and load alternating"
    flags = config["load"].split()  # "--ws-clients N --rps R", as passed to bench/load.py
    clients, rps = (flags[flags.index(f) + 1] for f in ("--ws-clients", "--rps"))
    load = f"{clients} WS clients + {rps} HTTP req/s"
    for key, label in (("idle", "idle"), ("load", load)):
        w = q[key]
        j = w["jitter_ms"]
        rows.append(
            _row(
                f"Tick jitter at 100 Hz, {label} (p50 / p99 / max)",
                f"{j['p50']:.2f} / {j['p99']:.2f} / {j['max']:.2f} ms; "
                f"{w['overruns']} overruns in {w['ticks']} ticks; daemon CPU "
                f"{w['daemon_cpu_percent']:.1f} %",
                "—",
                "measured",
                f"/metrics lupin_tick_jitter_seconds over {pooled} (quantiles: tick-weighted "
                "mean of the windows'), daemon and sim in their own processes"
                + ("; load from a second process" if key == "load" else ""),
            )
        )
    r = doc["refresh"]
    rows.append(
        _row(
            "Full-state refresh per joint (every servo, every tick)",
            f"{r['full_state_reads_per_s_per_servo']:.1f} Hz",
            "~8 Hz (one arm joint per 50 Hz cycle)",
            "reference",
            r["method"],
        )
    )
    sweep = doc["sweep"]
    per_rate = ", ".join(
        f"{hz} Hz: {w['overruns']} ({100 * (w['overrun_fraction'] or 0):.1f} %)"
        for hz, w in sweep["rates"].items()
    )
    top = max(int(hz) for hz in sweep["rates"])
    rows.append(
        _row(
            f"Tick rate sweep: overruns per rate ({window})",
            f"{per_rate}; highest with no overrun there or at any lower rate: "
            f"{_rate(sweep['highest_without_overrun_hz'], top)}; under 1 % likewise: "
            f"{_rate(sweep['highest_under_1pct_overruns_hz'], top)}",
            "50 Hz controller_manager",
            "reference",
            sweep["method"],
        )
    )
    return rows


def _rate(hz: int | None, top: int) -> str:
    """A sweep's answer; at the top of the sweep it is only a lower bound."""
    if hz is None:
        return "none"
    return f"{hz} Hz" + (" or more (the top of the sweep)" if hz == top else "")


def bus_rows(doc: dict[str, Any]) -> list[Row]:
    s = doc["sync_read"]
    lupin, sdk = s["lupin"], s["scservo_sdk"]
    return [
        _row(
            "CPU per full-state SYNC_READ (8 servos)",
            f"{1000 * lupin['cpu_s_per_transaction']:.2f} ms ({lupin['per_second']:.0f}/s)",
            f"scservo_sdk {1000 * sdk['cpu_s_per_transaction']:.2f} ms "
            f"({sdk['per_second']:.0f}/s): {s['sdk_cpu_over_lupin_cpu']:.1f}× Lupin's",
            "measured",
            "bench/bus.py: same wire-paced sim process, clients taking turns",
        )
    ]


def footprint_rows(doc: dict[str, Any]) -> list[Row]:
    c, m, r = doc["cpu"], doc["memory"], doc["start_to_ready_s"]
    return [
        _row(
            "Daemon CPU, idle / driving (HMI client, twist at 10 Hz)",
            f"{c['idle_percent']:.1f} % / {c['driving_percent']:.1f} % of one core",
            "—",
            "measured",
            c["method"] + ", /proc/PID/stat",
        ),
        _row(
            "Daemon memory (RSS idle / peak)",
            f"{m['rss_idle_kib'] / 1024:.1f} / {m['peak_rss_kib'] / 1024:.1f} MiB",
            "9 ROS nodes",
            "reference",
            m["method"],
        ),
        _row(
            "Start to READY=1 (spawn → sd_notify, p50 / max)",
            f"{r['p50']:.2f} / {r['max']:.2f} s",
            "—",
            "measured",
            "fake NOTIFY_SOCKET bound by the benchmark",
        ),
    ]


BUILDERS: dict[str, Callable[[dict[str, Any]], list[Row]]] = {
    "latency": latency_rows,
    "ticks": tick_rows,
    "bus": bus_rows,
    "footprint": footprint_rows,
}


def rows(results: dict[str, dict[str, Any]]) -> list[Row]:
    """The table for every benchmark that produced a result (a failed one is skipped)."""
    out: list[Row] = []
    for name, build in BUILDERS.items():
        doc = results.get(name)
        if doc is not None and "error" not in doc:
            out += build(doc)
    return out


def markdown(table: list[Row]) -> str:
    lines = ["| measure | Lupin | baseline | baseline is |", "|---|---|---|---|"]
    for row in table:
        cells = (row["measure"], row["lupin"], row["baseline"], row["baseline_kind"])
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines)
