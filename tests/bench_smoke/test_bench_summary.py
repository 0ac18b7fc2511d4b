"""The headline table's wording: what each cell claims is what was counted."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "bench"))

import summary  # noqa: E402  (bench/ is a folder of scripts, not a package)


def latency(next_tick: int, under: int, n: int = 200) -> dict[str, Any]:
    return {
        "latency_ms": {"n": n, "p50": 5.0, "p99": 10.5, "max": 10.7},
        "next_tick_write": next_tick,
        "under_one_period": under,
        "period_ms": 10.0,
    }


def test_the_one_tick_cell_states_both_rules() -> None:
    cell = summary._one_tick(latency(200, 194))
    assert cell == "200/200 on the next tick's write; 194/200 (97 %) under 10 ms"


def test_the_share_under_one_period_never_rounds_up_to_all() -> None:
    assert "(99 %)" in summary._one_tick(latency(200, 199))
