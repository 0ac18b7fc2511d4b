"""sd_notify without a dependency: readiness, watchdog and status for ``Type=notify``.

The protocol is one datagram of ``KEY=VALUE`` lines to the AF_UNIX socket named
in ``$NOTIFY_SOCKET`` (a leading ``@`` means the abstract namespace). systemd
passes the watchdog period in ``$WATCHDOG_USEC`` (for ``$WATCHDOG_PID`` only).

What the daemon promises with it (docs/operations.md):

* ``READY=1`` only once the bus is open and the first full state has been read,
  so ``systemctl start`` returning means the robot is really being controlled;
* ``WATCHDOG=1`` from the control tick itself (:class:`WatchdogPinger`), so a
  stalled loop stops the pings and systemd kills and restarts the daemon, and
  ExecStopPost's stop helper limps the arm it left energised;
* ``STOPPING=1`` and ``STATUS=`` lines for ``systemctl status``.

Sending never raises: a notify socket that went away must not take the control
tick with it. Failures are logged once.
"""

from __future__ import annotations

import logging
import math
import os
import socket
from collections.abc import Awaitable, Callable, Mapping

log = logging.getLogger(__name__)


def _address(raw: str) -> str | None:
    """The socket address for ``$NOTIFY_SOCKET``, or None if this module cannot speak it."""
    if raw.startswith("@"):
        return "\0" + raw[1:]  # Linux abstract namespace
    if raw.startswith("/"):
        return raw
    return None  # e.g. systemd's vsock: addresses; not used on a Pi


class SdNotifier:
    """A connected-less datagram sender to the service manager's notify socket."""

    def __init__(self, address: str) -> None:
        self.address = address
        self._sock: socket.socket | None = socket.socket(
            socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC | socket.SOCK_NONBLOCK
        )
        self._failed = False
        self.sent = 0

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None) -> SdNotifier | None:
        """The notifier systemd asked for, or None when not run as ``Type=notify``."""
        raw = (os.environ if env is None else env).get("NOTIFY_SOCKET", "")
        if not raw:
            return None
        address = _address(raw)
        if address is None:
            log.warning("NOTIFY_SOCKET=%r is not a unix socket path; not notifying", raw)
            return None
        return cls(address)

    def notify(self, *fields: str) -> bool:
        """Send ``KEY=VALUE`` fields as one datagram; False (logged once) if it did not go."""
        if self._sock is None:
            return False
        # One field per line; a newline inside a value would start a bogus field.
        payload = "\n".join(f.replace("\n", " ") for f in fields).encode()
        try:
            self._sock.sendto(payload, self.address)
        except OSError as exc:
            if not self._failed:
                log.warning("sd_notify to %r failed: %s", self.address.lstrip("\0"), exc)
                self._failed = True
            return False
        self.sent += 1
        return True

    def ready(self, status: str = "") -> bool:
        fields = ["READY=1"] + ([f"STATUS={status}"] if status else [])
        return self.notify(*fields)

    def watchdog(self) -> bool:
        return self.notify("WATCHDOG=1")

    def stopping(self, status: str = "") -> bool:
        fields = ["STOPPING=1"] + ([f"STATUS={status}"] if status else [])
        return self.notify(*fields)

    def status(self, text: str) -> bool:
        return self.notify(f"STATUS={text}")

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def watchdog_interval(env: Mapping[str, str] | None = None) -> float | None:
    """The watchdog period in seconds that systemd set for this process, or None.

    ``$WATCHDOG_PID``, when set, names the process the period is meant for; a
    child that inherited the environment must not ping on its parent's behalf.
    """
    env = os.environ if env is None else env
    try:
        usec = int(env.get("WATCHDOG_USEC", ""))
    except ValueError:
        return None
    if usec <= 0:
        return None
    pid = env.get("WATCHDOG_PID")
    if pid and pid != str(os.getpid()):
        return None
    return usec / 1e6


class WatchdogPinger:
    """``WATCHDOG=1`` at most every ``interval / 2``, driven by the control tick.

    Call :meth:`on_tick` from the tick (``ControlLoop.on_tick``). It is a plain
    function of ``now``, never a timer of its own: a timer would keep pinging
    while the tick is stuck, which is exactly what the watchdog exists to catch.
    """

    def __init__(self, notifier: SdNotifier, interval: float) -> None:
        if not interval > 0 or not math.isfinite(interval):
            raise ValueError(f"watchdog interval must be a positive number, got {interval!r}")
        self.notifier = notifier
        self.every = interval / 2
        self._last = -math.inf

    def on_tick(self, now: float) -> None:
        if now - self._last >= self.every:
            self._last = now
            self.notifier.watchdog()


async def announce_ready(
    notifier: SdNotifier,
    wait_ready: Callable[[float], Awaitable[bool]],
    status: str,
    *,
    poll: float = 5.0,
) -> None:
    """``READY=1`` once ``wait_ready(poll)`` says the first full state is in; STATUS until then.

    Run it as a task beside the daemon: a servo that never answers keeps the unit
    "activating" (with a status saying why) until ``TimeoutStartSec``, rather than
    reporting a robot ready that is not being read.
    """
    waited = 0.0
    while not await wait_ready(poll):
        waited += poll
        notifier.status(f"starting: no full joint state after {waited:.0f} s; still trying")
    notifier.ready(status)


__all__ = ["SdNotifier", "WatchdogPinger", "announce_ready", "watchdog_interval"]
