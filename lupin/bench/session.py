"""Opening the servo bus for a bench tool: through the adapter registry, closed in a finally.

The bench tools open the serial bus directly, so they need the daemon stopped
(bring-up seed). The serial adapter refuses a port another process holds for
writing and names its PID; the core must not import the adapter, so whatever
the opener raises is caught here and its message passed on whole.
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from typing import Any

from lupin import registry
from lupin.bus import ServoBus
from lupin.config_models import RobotProfile

# A bench tool is not on the control tick's clock: a reply that misses a tight
# margin there is a failed check or a refused calibration, not a late tick, so
# it waits longer and asks again more often (a silent id in the stray scan
# costs margin x attempts). Every request a tool repeats is idempotent.
BENCH_REPLY_MARGIN_S = 0.02
BENCH_RETRIES = 2


class BusOpenFailed(Exception):
    """The bus could not be opened (held by another process, missing, no permission)."""


@contextlib.asynccontextmanager
async def open_bench_bus(
    profile: RobotProfile,
    bus_port: str | None = None,
    *,
    adapter: str = "serial",
    **options: Any,
) -> AsyncIterator[ServoBus]:
    """The profile's bus on ``bus_port`` (default: the profile's port), closed on exit."""
    port = bus_port or profile.bus.port
    try:
        opener = registry.load("lupin.bus", adapter)
        link = await opener(port, profile.bus.baud, profile=profile, **options)
    except Exception as exc:  # PortBusy and friends live in the adapter: pass the message on
        raise BusOpenFailed(f"cannot open the servo bus on {port}: {exc}") from exc
    margin = max(profile.bus.reply_margin_s, BENCH_REPLY_MARGIN_S)
    retries = max(profile.bus.retries, BENCH_RETRIES)
    bus = ServoBus(link, reply_margin_s=margin, retries=retries)
    bus.start()
    try:
        yield bus
    finally:
        await bus.close()
