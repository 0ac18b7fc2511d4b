"""A stand-in for systemd's notify socket, shared by the operations tests."""

from __future__ import annotations

import socket
from dataclasses import dataclass, field


@dataclass
class NotifySocket:
    """A stand-in for systemd's notify socket: every datagram, stamped on arrival."""

    sock: socket.socket
    path: str
    messages: list[tuple[float, str]] = field(default_factory=list)

    def fields(self, key: str, since: float = float("-inf")) -> list[tuple[float, str]]:
        """Arrival time and full text of each message carrying field ``key`` (e.g. READY=1)."""
        return [(t, m) for t, m in self.messages if key in m.split("\n") and t >= since]

    def first(self, key: str) -> float | None:
        hits = self.fields(key)
        return hits[0][0] if hits else None
