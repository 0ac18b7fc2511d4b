"""Browser fixtures: the real daemon (``lupin run --sim``) and Debian's Chromium under Playwright.

The HMI is tested the way an operator uses it: a real daemon process on the
simulated bus, the page it serves, clicks and drags in a real browser, and the
daemon's own ``/api/state`` as the judge. Chromium is the system package
(``apt-get install chromium``), never a browser a tool downloads by itself, and
these tests skip with the reason when it or Playwright is missing.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from browser.harness import (
    CHROMIUM,
    CHROMIUM_ARGS,
    LAPTOP,
    RECORD_SENT,
    Lupin,
    connected,
    console_error,
    start_lupin,
    stop_lupin,
)

HERE = Path(__file__).parent


def missing() -> str | None:
    if not CHROMIUM.exists():
        return f"browser tests need Debian's Chromium at {CHROMIUM} (apt-get install chromium)"
    if importlib.util.find_spec("playwright") is None:
        return "browser tests need Playwright (pip install -e '.[test]')"
    return None


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    reason = missing()
    if reason is None:
        return
    for item in items:
        if HERE in item.path.parents:
            item.add_marker(pytest.mark.skip(reason=reason))


@pytest.fixture()
def lupin(tmp_path: Path) -> Iterator[Lupin]:
    home = tmp_path / "lupin-home"
    home.mkdir()
    daemon = start_lupin(home, tmp_path / "lupin.log")
    try:
        yield daemon
    finally:
        stop_lupin(daemon.proc)


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    from playwright.sync_api import sync_playwright

    pw = sync_playwright().start()
    try:
        b = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()
    finally:
        pw.stop()


@pytest.fixture()
def open_hmi(browser: Any, lupin: Lupin) -> Iterator[Callable[..., Any]]:
    """Open the HMI in a fresh context; fails the test on any page error."""
    contexts: list[Any] = []
    errors: list[str] = []

    def _open(viewport: dict[str, int] = LAPTOP, **options: Any) -> Any:
        context = browser.new_context(viewport=viewport, **options)
        contexts.append(context)
        context.add_init_script(RECORD_SENT)
        page = context.new_page()
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.on("console", lambda msg: errors.append(msg.text) if console_error(msg) else None)
        page.goto(lupin.url + "/")
        connected(page)
        return page

    try:
        yield _open
    finally:
        for context in contexts:
            context.close()
    assert not errors, f"the page logged errors: {errors}"
