"""docs/reliability.md stays true: every test it names exists, and it names every test here.

The table is the promise an operator reads; a renamed or deleted test would
leave a promise with nothing behind it, and a new test nobody listed would be
a promise nobody can find.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "reliability.md"
SUITE = ROOT / "tests" / "reliability"


def defined_tests(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    functions = (n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef))
    return {f.name for f in functions if f.name.startswith("test_")}


def all_tests() -> dict[str, set[str]]:
    return {str(p.relative_to(ROOT)): defined_tests(p) for p in ROOT.glob("tests/**/test_*.py")}


def cited() -> tuple[set[str], set[str]]:
    """(test names after ``::``, file paths) the document cites in backticks."""
    text = DOC.read_text(encoding="utf-8")
    spans = re.findall(r"`([^`\n]+)`", text)
    names = {m.group(1) for s in spans for m in re.finditer(r"::(test_\w+)", s)}
    paths = {m.group(0) for s in spans for m in re.finditer(r"tests/[\w/]+\.py", s)}
    return names, paths


def test_every_test_the_table_names_exists() -> None:
    tests = all_tests()
    everything = set().union(*tests.values())
    names, paths = cited()
    assert names, "the table names no tests"
    assert sorted(names - everything) == []
    assert sorted(p for p in paths if not (ROOT / p).is_file()) == []


def test_the_table_names_every_reliability_test() -> None:
    names, _ = cited()
    here = {
        f"{path}::{name}"
        for path, found in all_tests().items()
        if path.startswith("tests/reliability/") and path != "tests/reliability/test_table.py"
        for name in found
    }
    missing = sorted(t for t in here if t.split("::")[1] not in names)
    assert missing == [], "tests in tests/reliability that docs/reliability.md does not list"
