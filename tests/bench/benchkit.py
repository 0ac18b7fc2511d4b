"""Test kit for the bench tools: the simulator in the test's loop, the tool on a pseudo-terminal.

The simulator runs in the test's event loop (so a test can move limp joints by
hand, inject faults and read every packet); the tool runs as ``python -m
lupin ...`` with stdin, stdout and stderr on a pty the test opened, exactly as
at a terminal: prompts, the live table, Enter and Ctrl-C all go through it.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import os
import re
import signal
import subprocess
import sys
from collections.abc import Awaitable, Callable, Mapping, Sequence
from pathlib import Path

from lupin.config import load_profile
from lupin.config_models import RobotProfile
from lupin_adapters.sim import PtySimServer, SimulatedBus, build_sim_bus
from lupin_adapters.sim.link import sim_specs

MakeSim = Callable[..., Awaitable["Sim"]]
StartTool = Callable[..., "Tool"]
ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


@dataclasses.dataclass
class Sim:
    bus: SimulatedBus
    server: PtySimServer
    path: str
    profile: RobotProfile


async def start_sim(
    positions: Mapping[int, float] | None = None,
    *,
    extra_ids: Sequence[int] = (),
    p_gain: Mapping[int, int] | None = None,
) -> Sim:
    """The so101 profile's servos on a pty, starting at ``positions`` (counts) if given."""
    profile = load_profile("so101")
    specs = []
    for spec in sim_specs(profile):
        if positions and spec.id in positions:
            spec = dataclasses.replace(spec, position=positions[spec.id])
        if p_gain and spec.id in p_gain:
            spec = dataclasses.replace(spec, p_gain=p_gain[spec.id])
        specs.append(spec)
    specs += [dataclasses.replace(specs[0], id=i) for i in extra_ids]
    bus = build_sim_bus(specs)
    server = PtySimServer(bus, baud=profile.bus.baud)
    path = await server.start()
    return Sim(bus, server, path, profile)


class Tool:
    """``python -m lupin ARGS`` on a pseudo-terminal the test holds the master end of."""

    def __init__(self, args: Sequence[str], home: Path) -> None:
        master, slave = os.openpty()
        env = dict(os.environ, LUPIN_HOME=str(home), COLUMNS="200")
        env.pop("JOURNAL_STREAM", None)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "lupin", *args],
            stdin=slave,
            stdout=slave,
            stderr=slave,
            env=env,
            close_fds=True,
            start_new_session=True,  # its own session: our Ctrl-C is the one we send
        )
        os.close(slave)  # the child holds it now; EIO on the master means it has gone
        os.set_blocking(master, False)
        self.master: int | None = master
        self.raw = b""
        self._changed = asyncio.Event()
        asyncio.get_running_loop().add_reader(master, self._on_readable)

    @property
    def output(self) -> str:
        return ANSI.sub("", self.raw.decode(errors="replace")).replace("\r", "")

    def _on_readable(self) -> None:
        assert self.master is not None
        try:
            data = os.read(self.master, 65536)
        except BlockingIOError:
            return
        except OSError:  # EIO: every slave fd closed, the child has exited
            data = b""
        if not data:
            asyncio.get_running_loop().remove_reader(self.master)
        self.raw += data
        self._changed.set()

    async def expect(self, text: str, timeout: float = 20.0) -> str:
        """Wait until ``text`` appears in the output; fail with the output so far."""
        try:
            async with asyncio.timeout(timeout):
                while text not in self.output:
                    if self.proc.poll() is not None:
                        await asyncio.sleep(0.05)  # let the last bytes arrive
                        if text in self.output:
                            break
                        raise AssertionError(
                            f"exited {self.proc.returncode} before {text!r}:\n{self.output}"
                        )
                    self._changed.clear()
                    with contextlib.suppress(TimeoutError):
                        async with asyncio.timeout(0.1):
                            await self._changed.wait()
        except TimeoutError:
            raise AssertionError(f"no {text!r} within {timeout} s:\n{self.output}") from None
        return self.output

    def send(self, text: str) -> None:
        assert self.master is not None
        os.write(self.master, text.encode())

    def interrupt(self) -> None:
        self.proc.send_signal(signal.SIGINT)

    async def wait(self, timeout: float = 30.0) -> int:
        """The exit status, once the child has exited and its output is drained."""
        try:
            async with asyncio.timeout(timeout):
                # Polled, not waited on in a thread: the suite fails tests that leave threads.
                while self.proc.poll() is None:  # noqa: ASYNC110
                    await asyncio.sleep(0.02)
        except TimeoutError:
            raise AssertionError(f"still running after {timeout} s:\n{self.output}") from None
        await asyncio.sleep(0.05)
        return self.proc.returncode

    async def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            await self.wait(10)
        if self.master is not None:
            with contextlib.suppress(ValueError, OSError):
                asyncio.get_running_loop().remove_reader(self.master)
            os.close(self.master)
            self.master = None


def ramp(*points: float, step: float = 150.0) -> list[float]:
    """Positions from point to point in steps no bigger than ``step`` (a hand, not a jump)."""
    out = [points[0]]
    for target in points[1:]:
        while abs(target - out[-1]) > step:
            out.append(out[-1] + (step if target > out[-1] else -step))
        out += [target] * 3  # dwell at each stop, so the 20 Hz sampler sees it
    return out


def backups(home: Path) -> list[str]:
    """The offset backups in ``home``: the current one and any kept beside it."""
    return sorted(p.name for p in home.glob("arm_offsets_backup*.yaml"))


async def sweep_by_hand(
    bus: SimulatedBus, paths: Mapping[int, Sequence[float]], dwell: float = 0.05
) -> None:
    """Move the limp servos along ``paths`` (present counts, unwrapped) together."""
    for k in range(max(len(p) for p in paths.values())):
        for sid, path in paths.items():
            bus.servo(sid).move_by_hand(path[min(k, len(path) - 1)] % 4096)
        await asyncio.sleep(dwell)
