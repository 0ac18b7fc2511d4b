"""``bench/bus.py --smoke`` runs end to end and prints a well-formed result (numbers unjudged)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]


def positive(doc: dict[str, Any], *path: str) -> float:
    node: Any = doc
    for key in path:
        assert key in node, f"missing {'.'.join(path)}"
        node = node[key]
    assert isinstance(node, int | float) and node > 0, f"{'.'.join(path)} = {node!r}"
    return float(node)


def test_bench_bus_smoke(tmp_path: Path) -> None:
    output = tmp_path / "bus.json"
    proc = subprocess.run(
        [sys.executable, str(ROOT / "bench" / "bus.py"), "--smoke", "--output", str(output)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,  # must not depend on the working directory
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)  # exactly one JSON document on stdout
    assert json.loads(output.read_text()) == doc

    assert doc["benchmark"] == "bus"
    assert doc["config"]["servo_ids"] == [1, 2, 3, 4, 5, 6, 7, 9]
    assert doc["config"]["wire_pacing"] is True
    assert isinstance(doc["method"], str) and doc["method"]
    sync = doc["sync_read"]
    assert (sync["address"], sync["length"], sync["servos"]) == (56, 6, 8)
    for client in ("lupin", "scservo_sdk"):
        assert positive(doc, "sync_read", client, "transactions") == 20
        for key in ("wall_s", "per_second", "cpu_s_per_transaction"):
            positive(doc, "sync_read", client, key)
        assert isinstance(sync[client]["failures"], dict)
    positive(doc, "sync_read", "sdk_cpu_over_lupin_cpu")

    tick = doc["tick"]
    # 16-byte request, 8 replies of 12 bytes, a 26-byte goal write to 6 joints.
    assert tick["bytes"] == {
        "sync_read_request": 16,
        "sync_read_replies": 96,
        "goal_sync_write": 26,
        "total": 138,
    }
    assert positive(doc, "tick", "measured", "bytes_out_per_tick") == 16 + 26  # no retries
    positive(doc, "tick", "measured", "bytes_in_per_tick")
    positive(doc, "tick", "measured", "tick_hz_back_to_back")
    assert positive(doc, "tick", "max_tick_hz_at_baud") == round(1_000_000 / 1380, 1)
    # A fraction of the line's time at 100 ticks a second (13.8 %), as its name says.
    assert tick["bus_utilisation_fraction_at_100_hz_tick"] == round(1380e-6 * 100, 4)
    assert "bus_utilisation_at_100_hz_tick" not in tick
