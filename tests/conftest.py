"""Suite-wide health checks: every test leaves no stray threads or child processes.

python-can and pymodbus both check this after every test; a leaked reader
thread or daemon process is exactly the kind of bug that shows up on the robot
as a second opener of the bus.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

pytest_plugins = ["lupintest.fixtures"]


def _children() -> set[int]:
    me = str(os.getpid())
    found = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[1] == me and fields[0] != "Z":
            found.add(int(stat.parent.name))
    return found


@pytest.fixture(autouse=True)
def no_leaks() -> Iterator[None]:
    threads = {t.ident for t in threading.enumerate()}
    children = _children()
    yield
    deadline = time.monotonic() + 2.0
    while True:
        extra_threads = [
            t for t in threading.enumerate() if t.ident not in threads and t.is_alive()
        ]
        extra_children = _children() - children
        if not extra_threads and not extra_children:
            return
        if time.monotonic() > deadline:
            break
        time.sleep(0.02)
    assert not extra_threads, f"test leaked threads: {[t.name for t in extra_threads]}"
    assert not extra_children, f"test leaked child processes: {sorted(extra_children)}"


@pytest.fixture()
def lupin_home(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An empty $LUPIN_HOME so no test reads the developer's real calibration."""
    home = tmp_path / "lupin-home"
    home.mkdir()
    monkeypatch.setenv("LUPIN_HOME", str(home))
    return home
