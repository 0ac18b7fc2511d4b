"""A ``python -m lupin ...`` child on a pseudo-terminal the test holds the master end of.

Exactly as at a terminal: the tool sees a tty on stdin, stdout and stderr, so
its prompts, live tables, Enter and Ctrl-C all go through the pty. The bench
tools' tests and jog's tests share it.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import re
import signal
import subprocess
from collections.abc import Mapping, Sequence

from lupintest.harness import lupin_cmd

ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


class PtyTool:
    def __init__(self, args: Sequence[str], env: Mapping[str, str]) -> None:
        master, slave = os.openpty()
        self.proc = subprocess.Popen(
            lupin_cmd(*args),
            stdin=slave,
            stdout=slave,
            stderr=slave,
            env={**env, "COLUMNS": "200"},
            close_fds=True,
            start_new_session=True,  # its own session: our Ctrl-C is the one we send
        )
        os.close(slave)  # the child holds it now; EIO on the master means it has gone
        os.set_blocking(master, False)
        self.master: int | None = master
        self.raw = b""
        self.seen = 0  # expect_next() searches only after its previous match
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

    async def _find(self, text: str, start: int, timeout: float) -> int:
        try:
            async with asyncio.timeout(timeout):
                while (at := self.output.find(text, start)) < 0:
                    if self.proc.poll() is not None:
                        await asyncio.sleep(0.05)  # let the last bytes arrive
                        if (at := self.output.find(text, start)) >= 0:
                            return at
                        raise AssertionError(
                            f"exited {self.proc.returncode} before {text!r}:\n{self.output}"
                        )
                    self._changed.clear()
                    with contextlib.suppress(TimeoutError):
                        async with asyncio.timeout(0.1):
                            await self._changed.wait()
        except TimeoutError:
            raise AssertionError(f"no {text!r} within {timeout} s:\n{self.output}") from None
        return at

    async def expect(self, text: str, timeout: float = 20.0) -> str:
        """Wait until ``text`` appears anywhere in the output; return all of it."""
        await self._find(text, 0, timeout)
        return self.output

    async def expect_next(self, text: str, timeout: float = 15.0) -> str:
        """Wait for ``text`` after the previous match; return the output between the two."""
        at = await self._find(text, self.seen, timeout)
        chunk = self.output[self.seen : at + len(text)]
        self.seen = at + len(text)
        return chunk

    def send(self, text: str) -> None:
        assert self.master is not None
        os.write(self.master, text.encode())

    async def type(self, line: str, until: str) -> str:
        """Type a line and wait for ``until`` after it; return what the tool printed."""
        self.send(line + "\n")
        return await self.expect_next(until)

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
