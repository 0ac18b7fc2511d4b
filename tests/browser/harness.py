"""Helpers of the browser tests: the daemon as a subprocess, page helpers, paths and sizes.

Imports nothing from Playwright, so the suite can still be collected (and skip
with its reason) on a machine without it.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import time
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lupintest.harness import child_env, lupin_cmd

# Debian's package; LUPIN_CHROMIUM points elsewhere (or nowhere, to see the skip).
CHROMIUM = Path(os.environ.get("LUPIN_CHROMIUM", "/usr/bin/chromium"))
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--headless=new",
]
ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts"
LISTENING = re.compile(r"API listening on (https?://\S+)")
WS_REFUSED = re.compile(r"WebSocket connection to .* failed")
PHONE = {"width": 390, "height": 844}
LAPTOP = {"width": 1280, "height": 800}

# Records every frame the page sends on its WebSocket, so a test can count twists.
RECORD_SENT = """
(() => {
  window.__sent = [];
  const send = WebSocket.prototype.send;
  WebSocket.prototype.send = function (data) {
    try { window.__sent.push({t: performance.now(), frame: JSON.parse(data)}); } catch (e) {}
    return send.call(this, data);
  };
})();
"""


@dataclass
class Lupin:
    """A running ``lupin run --sim`` process and its HTTP API."""

    proc: subprocess.Popen[bytes]
    url: str
    log: Path
    home: Path

    def get(self, path: str) -> Any:
        with urllib.request.urlopen(self.url + path, timeout=5) as reply:
            return json.load(reply)

    def post(self, path: str, body: dict[str, Any]) -> Any:
        request = urllib.request.Request(
            self.url + path,
            data=json.dumps(body).encode(),
            headers={"Content-Type": "application/json"},
            method="POST",
        )
        with urllib.request.urlopen(request, timeout=5) as reply:
            return json.load(reply)

    @property
    def port(self) -> int:
        return int(self.url.rsplit(":", 1)[1])

    def stop(self) -> None:
        stop_lupin(self.proc)

    def start_again(self) -> None:
        """A daemon restart: a new process on the same port, home and log."""
        fresh = start_lupin(self.home, self.log, port=self.port)
        self.proc, self.url = fresh.proc, fresh.url

    def state(self) -> dict[str, Any]:
        state: dict[str, Any] = self.get("/api/state")
        return state

    def joint(self, name: str) -> dict[str, Any]:
        return next(j for j in self.state()["joints"] if j["name"] == name)

    def wait_for(
        self, what: str, check: Callable[[dict[str, Any]], bool], timeout: float = 5.0
    ) -> dict[str, Any]:
        """Poll ``/api/state`` until ``check`` holds; fail naming ``what``."""
        deadline = time.monotonic() + timeout
        while True:
            state = self.state()
            if check(state):
                return state
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out waiting for {what}; last state: {state}")
            time.sleep(0.05)


def start_lupin(
    home: Path, log: Path, port: int = 0, timeout: float = 15.0, token: str | None = None
) -> Lupin:
    env = child_env(home)
    env["LUPIN_AUTO_HOME"] = "false"  # the arm stays limp at boot: the test enables torque
    env.pop("LUPIN_TOKEN", None)
    if token is not None:
        env["LUPIN_TOKEN"] = token
    start = log.stat().st_size if log.exists() else 0  # a restart appends to the same log
    with log.open("ab") as out:
        proc = subprocess.Popen(
            lupin_cmd("run", "--sim", "--port", str(port)),
            stdout=out,
            stderr=subprocess.STDOUT,
            env=env,
        )
    deadline = time.monotonic() + timeout
    url = None
    while time.monotonic() < deadline and proc.poll() is None:
        text = log.read_bytes()[start:].decode(errors="replace")
        found = LISTENING.search(text)
        if found and "ready:" in text[found.end() :]:
            url = found.group(1)
            break
        time.sleep(0.05)
    if url is None:
        stop_lupin(proc)
        raise AssertionError(f"lupin run did not come up:\n{log.read_text(errors='replace')}")
    return Lupin(proc, url, log, home)


def stop_lupin(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def console_error(msg: Any) -> bool:
    # The browser itself logs every refused WebSocket attempt; the reconnect test causes those.
    return bool(msg.type == "error" and not WS_REFUSED.search(msg.text))


def connected(page: Any, timeout: float = 10.0) -> None:
    """Wait until the page has its hello and at least one state frame."""
    page.wait_for_function(
        "document.getElementById('conn-text').textContent === 'connected' &&"
        " document.getElementById('torque-text').textContent !== 'unknown'",
        timeout=timeout * 1000,
    )


def screenshot(page: Any, name: str) -> Path:
    ARTIFACTS.mkdir(exist_ok=True)
    path = ARTIFACTS / f"{name}.png"
    # Bytes, written here: with path= Playwright writes from an executor thread that would
    # outlive the test (and trip the suite's thread-leak check).
    path.write_bytes(page.screenshot(full_page=True))
    return path


def set_slider(page: Any, testid: str, value: float) -> None:
    """What a finger does to a range input: input events while dragging, change on release."""
    page.eval_on_selector(
        f"[data-testid='{testid}']",
        """(el, v) => {
             el.dispatchEvent(new PointerEvent('pointerdown', {bubbles: true}));
             el.value = String(v);
             el.dispatchEvent(new Event('input', {bubbles: true}));
             el.dispatchEvent(new Event('change', {bubbles: true}));
           }""",
        value,
    )
