"""The tick sweep's pure arithmetic: which rate counts as sustained, where to probe, pooling."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "bench"))

import ticks  # noqa: E402  (bench/ is a folder of scripts, not a package)


@pytest.mark.parametrize(
    ("passed", "expected"),
    [
        ({100: True, 200: False, 300: True}, 100),  # a lucky 300 Hz window does not count
        ({100: True, 125: True, 150: True, 200: False}, 150),
        ({300: True, 100: True, 200: True}, 300),  # order of sweeping does not matter
        ({100: False, 200: True}, None),  # even the lowest failed
        ({}, None),
    ],
)
def test_highest_sustained_needs_every_lower_rate_to_pass(
    passed: dict[int, bool], expected: int | None
) -> None:
    assert ticks.highest_sustained(passed) == expected


def test_next_probe_bisects_towards_the_first_failure_until_resolution() -> None:
    passed = {100: True, 200: False, 300: False, 400: False}
    assert ticks.next_probe(passed, 25) == 150
    assert ticks.next_probe(passed | {150: False}, 25) == 125
    assert ticks.next_probe(passed | {150: True}, 25) == 175
    assert ticks.next_probe(passed | {150: True, 175: True}, 25) is None  # 25 Hz apart
    # A pass above the first failure does not move the search past it.
    assert ticks.next_probe({100: True, 200: False, 300: True}, 25) == 150


def test_next_probe_has_nothing_to_do_at_either_end() -> None:
    assert ticks.next_probe({100: True, 200: True}, 25) is None  # nothing failed
    assert ticks.next_probe({100: False, 200: False}, 25) is None  # nothing passed


def window(ticks_: int, overruns: int) -> dict[str, Any]:
    return {"ticks": ticks_, "overruns": overruns}


def test_the_two_criteria() -> None:
    assert ticks.clean(window(2000, 0)) and not ticks.clean(window(2000, 1))
    assert ticks.nearly_clean(window(2000, 19)) and not ticks.nearly_clean(window(2000, 20))
    assert not ticks.clean(window(0, 0)) and not ticks.nearly_clean(window(0, 0))  # never ran


def full_window(p99: float, overruns: int, cpu: float) -> dict[str, Any]:
    return {
        "wall_s": 20.0,
        "nominal_hz": 100.0,
        "ticks": 2000,
        "overruns": overruns,
        "sync_reads": 2000,
        "servo_reads_missed": 0,
        "periods_over_1_5x_nominal": 0,
        "durations_over_half_nominal": 0,
        "durations_over_nominal": 0,
        "jitter_ms": {"p50": 0.2, "p90": 0.5, "p99": p99, "max": 2 * p99},
        "jitter_from_summary": "this window only",
        "tick_duration_mean_ms": 2.0,
        "daemon_cpu_percent": cpu,
        "daemon_rss_kib": 50_000,
    }


def test_pool_sums_counts_and_keeps_every_window() -> None:
    pooled = ticks.pool([full_window(1.0, 1, 4.0), full_window(2.0, 2, 6.0)])
    assert (pooled["windows"], pooled["ticks"], pooled["overruns"]) == (2, 4000, 3)
    assert pooled["jitter_ms"]["p99"] == 1.5  # between the windows' p99s
    assert pooled["jitter_ms"]["max"] == 4.0
    assert pooled["daemon_cpu_percent"] == 5.0
    assert [w["p99"] for w in pooled["jitter_ms_by_window"]] == [1.0, 2.0]
    assert pooled["jitter_from_summary"] == "each window only"
