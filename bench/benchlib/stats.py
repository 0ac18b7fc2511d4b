"""Percentile summaries, the same nearest-rank rule as the daemon's ``/metrics``."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any


def percentile(values: Sequence[float], q: float) -> float:
    """Nearest-rank percentile (``q`` in 0..1) of ``values``; NaN when empty."""
    if not values:
        return math.nan
    ordered = sorted(values)
    rank = max(1, math.ceil(q * len(ordered)))
    return ordered[min(rank, len(ordered)) - 1]


def summary(values: Sequence[float], *, scale: float = 1.0, digits: int = 3) -> dict[str, Any]:
    """n, p50, p99, max, min and mean of ``values`` times ``scale`` (None when empty)."""
    if not values:
        return {"n": 0, "p50": None, "p99": None, "max": None, "min": None, "mean": None}
    scaled = [v * scale for v in values]
    return {
        "n": len(scaled),
        "p50": round(percentile(scaled, 0.5), digits),
        "p99": round(percentile(scaled, 0.99), digits),
        "max": round(max(scaled), digits),
        "min": round(min(scaled), digits),
        "mean": round(sum(scaled) / len(scaled), digits),
    }


def ms(values: Sequence[float]) -> dict[str, Any]:
    """:func:`summary` of seconds, in milliseconds."""
    return summary(values, scale=1000.0, digits=3)
