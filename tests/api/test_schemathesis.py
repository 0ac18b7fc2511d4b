"""Schemathesis against the live OpenAPI document: no 5xx, no answer the document does not allow.

The daemon and the API run in the test's event loop (real daemon, pty sim, real
port); schemathesis is synchronous (requests), so it runs in a worker thread
that the test owns and joins. Positive and negative cases for every
operation, a bounded number of each, so the run stays well under a minute.
"""

from __future__ import annotations

import asyncio
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import pytest

from lupin.api import ApiServer

schemathesis = pytest.importorskip("schemathesis")

EXAMPLES = 25


def exercise(operation: Any, mode: Any, checks: list[Any], statuses: Counter[str]) -> None:
    """Run one operation's cases in one generation mode; raises on the first failure."""
    from hypothesis import HealthCheck, Phase, given, settings

    @given(case=operation.as_strategy(generation_mode=mode))
    @settings(
        max_examples=EXAMPLES,
        deadline=None,
        database=None,
        phases=[Phase.explicit, Phase.generate],
        suppress_health_check=list(HealthCheck),
    )
    def run(case: Any) -> None:
        response = case.call_and_validate(checks=checks, timeout=10)
        statuses[f"{operation.label} {response.status_code}"] += 1

    run()


def run_schemathesis(url: str) -> tuple[list[str], Counter[str]]:
    """(failures, status counts by "METHOD path status"); checks every response."""
    from hypothesis.errors import Unsatisfiable
    from schemathesis import GenerationMode
    from schemathesis import checks as st_checks

    checks = [
        st_checks.not_a_server_error,
        st_checks.status_code_conformance,
        st_checks.content_type_conformance,
        st_checks.response_schema_conformance,
        st_checks.negative_data_rejection,
    ]
    schema = schemathesis.openapi.from_url(url + "/api/openapi.json", timeout=10)
    failures: list[str] = []
    statuses: Counter[str] = Counter()
    for result in schema.get_all_operations():
        operation = result.ok()
        for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):
            try:
                exercise(operation, mode, checks, statuses)
            except Unsatisfiable:
                pass  # nothing to negate (no parameters and no body)
            except Exception as exc:  # a check failed: keep going, report them all
                failures.append(f"{operation.label} [{mode.value}]: {exc}")
    return failures, statuses


async def test_schemathesis_finds_no_5xx_and_no_schema_violation(api: ApiServer) -> None:
    loop = asyncio.get_running_loop()
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="schemathesis") as pool:
        failures, statuses = await loop.run_in_executor(pool, run_schemathesis, api.url)
    assert not failures, "\n\n".join(failures)
    # It really ran: every operation was called, and refusals were exercised too.
    operations = {key.rsplit(" ", 1)[0] for key in statuses}
    assert len(operations) >= 20, sorted(operations)
    codes = {int(key.rsplit(" ", 1)[1]) for key in statuses}
    assert {200, 400, 404} <= codes and not any(c >= 500 for c in codes)
