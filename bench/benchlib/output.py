"""Command-line boilerplate every benchmark shares: ``--smoke``, ``--output``, printing JSON."""

from __future__ import annotations

import argparse
import json
import os
import platform
from pathlib import Path
from typing import Any

RESULTS = Path(__file__).resolve().parents[1] / "results"


def parser(description: str | None, name: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--smoke", action="store_true", help="tiny counts (for the test suite)")
    p.add_argument(
        "--output",
        type=Path,
        help=f"where to write the JSON as well (default {RESULTS / (name + '.json')}; "
        "none with --smoke)",
    )
    return p


def machine() -> dict[str, Any]:
    """What the numbers were measured on."""
    return {
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "machine": platform.machine(),
        # Other work on the machine shows up in every timing: say how busy it was.
        "loadavg_1min": round(os.getloadavg()[0], 2),
    }


def emit(result: dict[str, Any], name: str, args: argparse.Namespace) -> None:
    """Print ``result`` as one JSON document and write it where asked."""
    text = json.dumps(result, indent=2)
    print(text, flush=True)
    output = args.output or (None if args.smoke else RESULTS / f"{name}.json")
    if output is not None:
        output.parent.mkdir(parents=True, exist_ok=True)
        output.write_text(text + "\n")
