"""sd_notify: the datagrams, the environment, and the tick-driven watchdog pinger."""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from lupin.sdnotify import SdNotifier, WatchdogPinger, announce_ready, watchdog_interval


def recv_all(sock: socket.socket) -> list[str]:
    out = []
    while True:
        try:
            out.append(sock.recv(4096).decode())
        except BlockingIOError:
            return out


@pytest.fixture()
def receiver(notify_path: str) -> Iterator[socket.socket]:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(notify_path)
    sock.setblocking(False)
    yield sock
    sock.close()


def test_ready_status_stopping_watchdog_reach_a_path_socket(
    receiver: socket.socket, notify_path: str
) -> None:
    n = SdNotifier.from_env({"NOTIFY_SOCKET": notify_path})
    assert n is not None
    assert n.ready("ready: so101")
    assert n.status("heal: healthy")
    assert n.watchdog()
    assert n.stopping("stopping")
    n.close()
    assert recv_all(receiver) == [
        "READY=1\nSTATUS=ready: so101",
        "STATUS=heal: healthy",
        "WATCHDOG=1",
        "STOPPING=1\nSTATUS=stopping",
    ]


def test_abstract_namespace_address() -> None:
    name = f"lupin-test-{os.getpid()}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.setblocking(False)
    try:
        n = SdNotifier.from_env({"NOTIFY_SOCKET": "@" + name})
        assert n is not None and n.address == "\0" + name
        assert n.ready()
        n.close()
        assert recv_all(sock) == ["READY=1"]
    finally:
        sock.close()


def test_a_newline_in_a_status_cannot_inject_a_field(
    receiver: socket.socket, notify_path: str
) -> None:
    n = SdNotifier(notify_path)
    n.status("bus error\nREADY=1")
    n.close()
    assert recv_all(receiver) == ["STATUS=bus error READY=1"]


def test_not_under_systemd_means_no_notifier(caplog: pytest.LogCaptureFixture) -> None:
    assert SdNotifier.from_env({}) is None
    assert SdNotifier.from_env({"NOTIFY_SOCKET": ""}) is None
    with caplog.at_level(logging.WARNING):
        assert SdNotifier.from_env({"NOTIFY_SOCKET": "vsock:2:1234"}) is None
    assert "not a unix socket path" in caplog.text


def test_a_vanished_socket_never_raises_and_is_logged_once(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    n = SdNotifier(str(tmp_path / "gone.sock"))
    with caplog.at_level(logging.WARNING):
        assert not n.watchdog()
        assert not n.watchdog()
    assert caplog.text.count("sd_notify") == 1
    n.close()
    assert not n.ready()  # closed: still no exception


@pytest.mark.parametrize(
    ("env", "expected"),
    [
        ({}, None),
        ({"WATCHDOG_USEC": "2000000"}, 2.0),
        ({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": str(os.getpid())}, 2.0),
        ({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": "1"}, None),  # meant for another process
        ({"WATCHDOG_USEC": "0"}, None),
        ({"WATCHDOG_USEC": "soon"}, None),
    ],
)
def test_watchdog_interval(env: dict[str, str], expected: float | None) -> None:
    assert watchdog_interval(env) == expected


class CountingNotifier(SdNotifier):
    def __init__(self) -> None:
        super().__init__("\0unused")
        self.pings: list[float] = []
        self.now = 0.0
        self.fields: list[tuple[str, ...]] = []

    def notify(self, *fields: str) -> bool:
        self.fields.append(fields)
        if fields == ("WATCHDOG=1",):
            self.pings.append(self.now)
        return True


def test_pinger_pings_at_half_the_interval_and_only_when_ticked() -> None:
    n = CountingNotifier()
    pinger = WatchdogPinger(n, 2.0)
    for i in range(301):  # 3 s of 100 Hz ticks
        n.now = i * 0.01
        pinger.on_tick(n.now)
    assert n.pings == pytest.approx([0.0, 1.0, 2.0, 3.0])
    # No tick, no ping: nothing arrives however much time passes.
    n.now = 10.0
    assert n.pings[-1] == pytest.approx(3.0)
    pinger.on_tick(10.0)
    assert n.pings[-1] == 10.0
    n.close()


@pytest.mark.parametrize("bad", [0.0, -1.0, float("inf"), float("nan")])
def test_pinger_refuses_a_nonsense_interval(bad: float) -> None:
    n = CountingNotifier()
    with pytest.raises(ValueError):
        WatchdogPinger(n, bad)
    n.close()


async def test_announce_ready_waits_for_the_first_full_state() -> None:
    n = CountingNotifier()
    answers = iter([False, False, True])
    polls: list[float] = []

    async def wait_ready(timeout: float) -> bool:
        polls.append(timeout)
        return next(answers)

    await announce_ready(n, wait_ready, "ready: so101", poll=5.0)
    assert polls == [5.0, 5.0, 5.0]
    assert n.fields == [
        ("STATUS=starting: no full joint state after 5 s; still trying",),
        ("STATUS=starting: no full joint state after 10 s; still trying",),
        ("READY=1", "STATUS=ready: so101"),
    ]
    n.close()
