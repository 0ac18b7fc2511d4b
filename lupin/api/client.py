"""A small HTTP client of the running daemon, for ``lupin heal`` and the other CLI clients.

It finds the daemon (``--url``, ``$LUPIN_URL``, default http://127.0.0.1:8080),
sends the token (``--token``, ``$LUPIN_TOKEN``) and turns every way of failing
into one :class:`ApiClientError` with a message an operator can act on and a
sysexits-style exit code.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from types import TracebackType
from typing import Any

import aiohttp

from lupin.api.security import TOKEN_ENV

DEFAULT_URL = "http://127.0.0.1:8080"
URL_ENV = "LUPIN_URL"
EXIT_FAILED = 1
EXIT_UNAVAILABLE = 69  # EX_UNAVAILABLE: no daemon answering
EXIT_TEMPFAIL = 75  # EX_TEMPFAIL: the daemon did not answer in time
EXIT_NOPERM = 77  # EX_NOPERM: token missing or wrong


class ApiClientError(Exception):
    """A request that did not succeed: ``code`` is the daemon's error code when it refused.

    A refusal (``exit_code`` 1) carries the daemon's ``code`` (``too_far``,
    ``torque_off``, ``unknown_pose``...) and ``reason`` (its message alone), so a
    client can add advice for the cases it knows; every other failure has
    ``code`` None.
    """

    def __init__(
        self,
        message: str,
        exit_code: int = EXIT_FAILED,
        status: int | None = None,
        *,
        code: str | None = None,
        reason: str | None = None,
    ):
        super().__init__(message)
        self.exit_code = exit_code
        self.status = status
        self.code = code
        self.reason = reason if reason is not None else message


class ApiClient:
    def __init__(
        self,
        url: str | None = None,
        token: str | None = None,
        *,
        env: Mapping[str, str] | None = None,
        timeout_s: float = 60.0,
    ) -> None:
        env = os.environ if env is None else env
        self.url = (url or env.get(URL_ENV) or DEFAULT_URL).rstrip("/")
        self.token = token or env.get(TOKEN_ENV) or None
        self.timeout = aiohttp.ClientTimeout(total=timeout_s)
        self._session: aiohttp.ClientSession | None = None

    async def __aenter__(self) -> ApiClient:
        headers = {"Authorization": f"Bearer {self.token}"} if self.token else {}
        self._session = aiohttp.ClientSession(headers=headers, timeout=self.timeout)
        return self

    async def __aexit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self._session is not None:
            await self._session.close()
            self._session = None

    async def request(self, method: str, path: str, body: Any = None) -> Any:
        """The JSON answer of a 2xx, or ApiClientError saying what went wrong."""
        assert self._session is not None, "use ApiClient as an async context manager"
        try:
            async with self._session.request(method, self.url + path, json=body) as resp:
                try:
                    data = await resp.json(content_type=None)
                except ValueError:
                    data = None
                status = resp.status
        except aiohttp.ClientConnectorError as exc:
            raise ApiClientError(
                f"no Lupin daemon answering at {self.url} (is `lupin run` running?): "
                f"{exc.os_error.strerror or exc}",
                EXIT_UNAVAILABLE,
            ) from None
        except TimeoutError:
            raise ApiClientError(
                f"the daemon at {self.url} did not answer within {self.timeout.total} s",
                EXIT_TEMPFAIL,
            ) from None
        except aiohttp.ClientError as exc:
            raise ApiClientError(f"talking to {self.url}: {exc}", EXIT_UNAVAILABLE) from None
        if 200 <= status < 300 and isinstance(data, dict):
            return data
        error = data.get("error") if isinstance(data, dict) else None
        if not isinstance(error, dict):
            raise ApiClientError(
                f"{self.url} answered {status} without a Lupin error body: is it a Lupin daemon?",
                EXIT_UNAVAILABLE,
                status,
            )
        code, reason = str(error.get("code")), str(error.get("message"))
        message = f"{reason} ({code})"
        if status == 401:
            hint = "" if self.token else f"; pass --token or set {TOKEN_ENV}"
            raise ApiClientError(
                f"refused: {message}{hint}", EXIT_NOPERM, status, code=code, reason=reason
            )
        raise ApiClientError(f"refused: {message}", EXIT_FAILED, status, code=code, reason=reason)
