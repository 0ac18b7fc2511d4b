"""Logging set up for a systemd service as much as for a terminal.

Under systemd (``JOURNAL_STREAM`` set) each line carries the journald priority
prefix (``<3>`` error ... ``<7>`` debug) and no timestamp, since journald adds
its own; on a terminal lines get a time and, only on a TTY, colour.
"""

from __future__ import annotations

import logging
import os
import sys

LEVELS = ("debug", "info", "warning", "error", "critical")

_JOURNAL_PRIORITY = {
    logging.DEBUG: 7,
    logging.INFO: 6,
    logging.WARNING: 4,
    logging.ERROR: 3,
    logging.CRITICAL: 2,
}
_COLOURS = {logging.WARNING: "\033[33m", logging.ERROR: "\033[31m", logging.CRITICAL: "\033[1;31m"}


class JournalFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        prio = _JOURNAL_PRIORITY.get(record.levelno, 6)
        text = super().format(record)
        return "\n".join(f"<{prio}>{line}" for line in text.splitlines())


class TerminalFormatter(logging.Formatter):
    def __init__(self, colour: bool) -> None:
        super().__init__("%(asctime)s %(levelname)-7s %(name)s: %(message)s", "%H:%M:%S")
        self.colour = colour

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        start = _COLOURS.get(record.levelno) if self.colour else None
        return f"{start}{text}\033[0m" if start else text


def setup_logging(level: str = "info", stream: object = None) -> None:
    """Configure the root logger once; safe to call again (replaces handlers)."""
    out = stream if stream is not None else sys.stderr
    handler = logging.StreamHandler(out)  # type: ignore[arg-type]
    if os.environ.get("JOURNAL_STREAM"):
        handler.setFormatter(JournalFormatter("%(name)s: %(message)s"))
    else:
        isatty = getattr(out, "isatty", lambda: False)()
        handler.setFormatter(
            TerminalFormatter(colour=bool(isatty) and "NO_COLOR" not in os.environ)
        )
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level.upper())
    # aiohttp's access log is noise at 100s of requests per second.
    logging.getLogger("aiohttp.access").setLevel(logging.WARNING)


class Throttled:
    """Log a recurring failure once, then at most every ``every`` seconds with a count.

    A bus that is unplugged fails at the tick rate; a hundred tracebacks a
    second would bury the one line an operator needs in the journal.
    """

    def __init__(self, logger: logging.Logger, every: float = 5.0) -> None:
        self.logger = logger
        self.every = every
        self._last: dict[str, float] = {}
        self._count: dict[str, int] = {}

    def exception(self, key: str, msg: str, now: float) -> None:
        self._count[key] = self._count.get(key, 0) + 1
        last = self._last.get(key)
        if last is None or now - last >= self.every:
            n = self._count.pop(key)
            suffix = f" ({n} times since the last report)" if n > 1 else ""
            self.logger.exception("%s%s", msg, suffix)
            self._last[key] = now
