"""``bench/run_all.py --smoke`` runs every benchmark end to end, so the harness cannot rot.

The numbers are not judged (a test is no place for a timing); their presence,
their counts and their shape are, and so is the README table's rewriting.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "bench"))

import run_all  # noqa: E402  (bench/ is a folder of scripts, not a package)


def test_run_all_smoke(tmp_path: Path) -> None:
    proc = subprocess.run(
        [
            sys.executable,
            str(ROOT / "bench" / "run_all.py"),
            "--smoke",
            "--output-dir",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)  # exactly one JSON document on stdout
    assert json.loads((tmp_path / "run_all.json").read_text()) == doc
    assert doc["failed"] == []
    assert set(doc["benchmarks"]) == {"bus", "latency", "ticks", "footprint"}
    for name in doc["benchmarks"]:
        assert json.loads((tmp_path / f"{name}.json").read_text())["benchmark"] == name

    latency: dict[str, Any] = doc["benchmarks"]["latency"]
    for key, n in (("stop", 5), ("estop_http", 3), ("estop_ws", 3)):
        got = latency[key]
        # Every stimulus was seen at the servos (none missed) and judged against one tick.
        assert got["latency_ms"]["n"] + got["missed"] == n, key
        assert got["missed"] == 0, key
        assert 0 <= got["within_one_tick"] <= n
    assert latency["wire"]["idle"]["bytes_per_tick"] > 0

    ticks = doc["benchmarks"]["ticks"]
    assert set(ticks["quality_100hz"]) >= {"idle", "load"}
    assert ticks["quality_100hz"]["load"]["ticks"] > 0
    assert ticks["refresh"]["servos"] == 8

    footprint = doc["benchmarks"]["footprint"]
    assert footprint["start_to_ready_s"]["n"] == 1
    assert footprint["memory"]["peak_rss_kib"] > 0

    measures = [row["measure"] for row in doc["table"]]
    assert any(m.startswith("Stop: dead-man release") for m in measures)
    assert any(m.startswith("CPU per full-state SYNC_READ") for m in measures)
    assert {row["baseline_kind"] for row in doc["table"]} <= {"measured", "reference", "target"}


def test_a_failed_benchmark_is_recorded_and_the_others_still_run(tmp_path: Path) -> None:
    result = run_all.run_one("no_such_benchmark", smoke=True, out_dir=None, budget_s=30)
    assert "error" in result and "exit" in result["error"]


def test_readme_table_is_replaced_between_the_markers(tmp_path: Path) -> None:
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n{run_all.BEGIN}\nold table\n{run_all.END}\nafter\n")
    run_all.update_readme("| new |", "python bench/run_all.py --readme", "2026-11-22", readme)
    text = readme.read_text()
    assert "old table" not in text and "| new |" in text
    assert text.endswith(f"{run_all.END}\nafter\n")

    readme.write_text("# no markers\n")
    with pytest.raises(SystemExit, match="markers"):
        run_all.update_readme("| new |", "cmd", "today", readme)
    assert readme.read_text() == "# no markers\n"


def test_the_readme_carries_the_table() -> None:
    text = (ROOT / "README.md").read_text()
    table = text.split(run_all.BEGIN, 1)[1].split(run_all.END, 1)[0]
    assert "python bench/run_all.py --readme" in table
    assert "| Stop: dead-man release" in table
