"""Every benchmark in one run: one JSON document, the headline table, and the README's copy of it.

Runs ``bus``, ``latency``, ``ticks`` and ``footprint`` one after the other, each
as its own ``python bench/NAME.py`` process (a fresh interpreter and event loop,
so one benchmark's garbage, threads or sockets never weigh on the next), and
collects what each printed. A benchmark that fails or times out is recorded as
``{"error": ...}`` with the tail of its stderr and the others still run; the
exit status is then 1.

Output: one JSON document on stdout (``benchmarks`` = each result, ``table`` =
the headline rows from :mod:`summary`), also written to
``bench/results/run_all.json`` and each result to ``bench/results/NAME.json``.
``--readme`` rewrites the table between the markers in README.md.

    python bench/run_all.py --readme      # the full run, about 3.5 minutes on 2 cores
    python bench/run_all.py --smoke       # tiny counts, writes nothing unless --output-dir

The full run measured 3.6 minutes on 2 cores (2026-11-24; ticks 130 s of it).
Each benchmark has a budget (``BENCHMARKS``) and the run as a whole one more
(``TOTAL_BUDGET_S``, nine minutes): a benchmark still running at either is
killed and recorded as an error, so the run always ends inside ten minutes.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import reference
import summary
from benchlib import output

HERE = Path(__file__).resolve().parent
README = HERE.parent / "README.md"
BEGIN, END = "<!-- bench:begin -->", "<!-- bench:end -->"
# In running order, each with the wall time it may take before it is killed and recorded as
# an error: 2-4x what it took (bus 10 s, latency 52 s, footprint 24 s; ticks 76 s before its
# finer sweep and alternating windows, 130 s measured since). They add up to 525 s.
BENCHMARKS: dict[str, float] = {"bus": 45.0, "latency": 120.0, "ticks": 300.0, "footprint": 60.0}
TOTAL_BUDGET_S = 540.0  # ten minutes less a minute's margin for start-up and the table


def run_one(name: str, smoke: bool, out_dir: Path | None, budget_s: float) -> dict[str, Any]:
    cmd = [sys.executable, str(HERE / f"{name}.py")]
    if smoke:
        cmd.append("--smoke")
    if out_dir is not None:
        cmd += ["--output", str(out_dir / f"{name}.json")]
    t0 = time.monotonic()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=budget_s, check=False)
    except subprocess.TimeoutExpired:
        return {"error": f"did not finish within {budget_s:.0f} s"}
    wall = round(time.monotonic() - t0, 1)
    print(f"run_all: {name} exit {proc.returncode} in {wall} s", file=sys.stderr, flush=True)
    if proc.returncode != 0:
        return {"error": f"exit {proc.returncode}", "stderr_tail": proc.stderr[-2000:]}
    try:
        doc: dict[str, Any] = json.loads(proc.stdout)
    except json.JSONDecodeError as exc:
        return {"error": f"printed no JSON document: {exc}", "stdout_head": proc.stdout[:500]}
    doc["wall_s"] = wall
    return doc


def update_readme(table_md: str, command: str, when: str, path: Path = README) -> None:
    """Replace the text between the bench markers; refuse (loudly) if they are missing."""
    text = path.read_text()
    if BEGIN not in text or END not in text:
        raise SystemExit(f"run_all: {path} has no {BEGIN} ... {END} markers to fill")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    body = f"\n_Measured {when} by `{command}`._\n\n{table_md}\n"
    path.write_text(head + BEGIN + body + END + tail)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--smoke", action="store_true", help="tiny counts (for the test suite)")
    p.add_argument(
        "--output-dir",
        type=Path,
        help=f"where the JSON files go (default {output.RESULTS}; none with --smoke)",
    )
    p.add_argument("--only", nargs="+", choices=list(BENCHMARKS), help="a subset, in order")
    p.add_argument("--readme", action="store_true", help="rewrite the table in README.md")
    args = p.parse_args(argv)
    if args.readme and (args.smoke or args.only):
        p.error("--readme takes the full run: not with --smoke or --only")
    out_dir: Path | None = args.output_dir or (None if args.smoke else output.RESULTS)
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)

    t0 = time.monotonic()
    results: dict[str, dict[str, Any]] = {}
    for name, budget in BENCHMARKS.items():
        if args.only and name not in args.only:
            continue
        left = TOTAL_BUDGET_S - (time.monotonic() - t0)
        if left < 1:
            results[name] = {"error": f"not run: the run's {TOTAL_BUDGET_S:.0f} s were spent"}
            continue
        results[name] = run_one(name, args.smoke, out_dir, min(budget, left))
    table = summary.rows(results)
    doc = {
        "benchmark": "run_all",
        "smoke": args.smoke,
        "machine": output.machine(),
        "wall_s": round(time.monotonic() - t0, 1),
        "failed": sorted(n for n, r in results.items() if "error" in r),
        "table": table,
        "benchmarks": results,
        # What the ROS graph's numbers are (documented in the seeds, never measured here).
        "reference": reference.reference(),
    }
    text = json.dumps(doc, indent=2)
    print(text, flush=True)
    if out_dir is not None:
        (out_dir / "run_all.json").write_text(text + "\n")
    if args.readme and not doc["failed"]:
        today = time.strftime("%Y-%m-%d")
        update_readme(summary.markdown(table), "python bench/run_all.py --readme", today)
    return 1 if doc["failed"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
