"""Schemathesis, hostile: the full live OpenAPI document, every check, then the servos are asked.

tests/api/test_schemathesis.py already runs positive and negative cases over every
operation with five named checks. This adds what that cannot say:

* **negative data moves nothing**: every operation fed only invalid input (every
  schemathesis check enabled, not five) and afterwards not one write reached any
  servo, the E-stop and torque are as they were, the tick still runs;
* **stateful**: schemathesis' state machine follows the document's links (teach a
  pose with PUT, then read, go to, forget it, read it again) with every check,
  including the stateful ones (use after free, resource availability), and
  afterwards every goal the servos received can be traced to a command the API
  accepted, inside the joint's limits and the base's speed limit.

The daemon and the API run in the test's event loop; schemathesis is synchronous
(requests), so it runs in a worker thread the test owns and joins. Hypothesis is
seeded from ``$LUPIN_FUZZ_SEED`` (printed), so a failure replays.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from lupin.api.routes import ROUTES
from lupin.joints import RAD_PER_COUNT
from lupintest.harness import Sim

from .helpers import get_json, post, running_api, running_daemon
from .hostile_helpers import assert_nothing_written, assert_still_ticking, fuzz_seed

schemathesis = pytest.importorskip("schemathesis")

NEGATIVE_EXAMPLES = 25  # per operation; ~22 operations
STATEFUL_EXAMPLES = 50  # scenarios, each up to STATEFUL_STEPS calls
STATEFUL_STEPS = 10


@dataclass(frozen=True)
class Call:
    t: float  # time.monotonic() when the request was sent (the sim's clock)
    label: str  # "METHOD /template"
    status: int
    body: Any


def _settings(examples: int, **extra: Any) -> Any:
    from hypothesis import HealthCheck, settings

    return settings(
        max_examples=examples,
        deadline=None,
        database=None,
        suppress_health_check=list(HealthCheck),
        **extra,
    )


def run_negative(url: str, seed: int) -> tuple[list[str], Counter[str]]:
    """Only invalid input, every check; (failures, status counts by "METHOD path status")."""
    from hypothesis import Phase, given
    from hypothesis import seed as hseed
    from hypothesis.errors import Unsatisfiable
    from schemathesis import GenerationMode

    schema = schemathesis.openapi.from_url(url + "/api/openapi.json", timeout=10)
    failures: list[str] = []
    statuses: Counter[str] = Counter()
    for result in schema.get_all_operations():
        operation = result.ok()

        @hseed(seed)
        @given(case=operation.as_strategy(generation_mode=GenerationMode.NEGATIVE))
        @_settings(NEGATIVE_EXAMPLES, phases=[Phase.explicit, Phase.generate])
        def run(case: Any) -> None:
            if not case.meta.generation.mode.is_negative:
                return  # nothing left to negate (an optional body left out): a valid call
            response = case.call_and_validate(timeout=10)  # checks=None: every check
            statuses[f"{operation.label} {response.status_code}"] += 1  # noqa: B023

        try:
            run()
        except Unsatisfiable:
            pass  # nothing to negate (no parameters and no body)
        except Exception as exc:  # a check failed: keep going, report them all
            failures.append(f"{operation.label}: {exc}")
    return failures, statuses


def run_stateful(url: str, seed: int, calls: list[Call], poses: Path) -> None:
    """The document's links as a state machine, every check; raises on the first failure.

    Each scenario starts with no taught pose, so a scenario replays the same way
    (Hypothesis re-runs a failing one, and refuses one whose answers changed).
    """
    from hypothesis import seed as hseed

    schema = schemathesis.openapi.from_url(url + "/api/openapi.json", timeout=10)
    base = schema.as_state_machine()
    sent: dict[str, float] = {}

    class Workflow(base):  # type: ignore[misc, valid-type]
        def setup(self) -> None:
            poses.unlink(missing_ok=True)

        def before_call(self, case: Any) -> None:
            sent[case.id] = time.monotonic()

        def get_call_kwargs(self, case: Any) -> dict[str, Any]:
            return {"timeout": 10}

        def after_call(self, response: Any, case: Any) -> None:
            super().after_call(response, case)
            label = f"{case.method.upper()} {case.operation.path}"
            calls.append(Call(sent.pop(case.id), label, response.status_code, case.body))

    # hypothesis.seed on a state machine class seeds its run.
    hseed(seed)(Workflow).run(
        settings=_settings(STATEFUL_EXAMPLES, stateful_step_count=STATEFUL_STEPS)
    )


async def test_negative_data_on_every_operation_moves_nothing(
    sim: Sim, http: aiohttp.ClientSession, caplog: pytest.LogCaptureFixture
) -> None:
    seed = fuzz_seed("schemathesis negative")
    caplog.set_level(logging.INFO)
    async with running_daemon(sim) as daemon, running_api(daemon) as api:
        before = await get_json(http, api.url + "/api/state")
        t0 = time.monotonic()
        loop = asyncio.get_running_loop()
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="schemathesis") as pool:
            failures, statuses = await loop.run_in_executor(pool, run_negative, api.url, seed)
        assert not failures, "\n\n".join(failures)
        # It really ran: every operation with an input to negate (a body or a path
        # parameter) was fed invalid input, and each was refused 4xx.
        operations = {key.rsplit(" ", 1)[0] for key in statuses}
        negatable = {f"{r.method} {r.path}" for r in ROUTES if r.request or "{" in r.path}
        assert negatable <= operations, sorted(negatable - operations)
        codes = {int(key.rsplit(" ", 1)[1]) for key in statuses}
        assert 400 in codes and all(400 <= c < 500 for c in codes), statuses
        # Nothing moved: not one write reached a servo; the robot's state is as it was.
        assert_nothing_written(sim, t0, "invalid input over HTTP")
        after = await get_json(http, api.url + "/api/state")
        assert after["estop"] == before["estop"] is False
        assert [j["torque"] for j in after["joints"]] == [j["torque"] for j in before["joints"]]
        assert after["mux"]["active"] is None
        await assert_still_ticking(sim, daemon)
    bad = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert not bad, f"invalid input reached an unhandled error: {bad}"


async def test_stateful_links_every_check_and_only_commanded_motion(
    sim: Sim, http: aiohttp.ClientSession, lupin_home: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Torque on first, so a pose that is gone to really moves: every goal the servos
    then receive follows an accepted go, inside its joint's window; nothing else moves."""
    seed = fuzz_seed("schemathesis stateful")
    caplog.set_level(logging.INFO)
    calls: list[Call] = []
    async with running_daemon(sim) as daemon, running_api(daemon) as api:
        status, body = await post(http, api.url + "/api/arm/torque", {"enabled": True})
        assert (status, body) == (200, {"torque": "on"})
        await asyncio.sleep(0.3)  # the seeded hold goals have gone out
        t0 = time.monotonic()
        loop = asyncio.get_running_loop()
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="schemathesis") as pool:
            await loop.run_in_executor(
                pool, run_stateful, api.url, seed, calls, lupin_home / "poses.yaml"
            )
        t_end = time.monotonic()
        await assert_still_ticking(sim, daemon)
        geometry = daemon.geometry
    bad = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert not bad, f"the API or daemon logged errors: {bad}"

    # It really ran: the links were followed (a taught pose read back and forgotten).
    labels = Counter(f"{c.label} {c.status}" for c in calls)
    print(sorted(labels.items()))
    followed = {
        "PUT /api/arm/poses/{pose} 200",
        "GET /api/arm/poses/{pose} 200",
        "DELETE /api/arm/poses/{pose} 200",
    }
    assert followed <= set(labels), labels

    # Every goal the servos received follows an accepted go, inside the joint's window;
    # the torque stayed as commanded (on) and the wheels were never written.
    goes = [c.t for c in calls if c.label == "POST /api/arm/poses/{pose}/go" and c.status == 200]
    by_id = {g.id: g for g in geometry.values()}
    tolerance = 1.5 * RAD_PER_COUNT
    for w in sim.bus.writes(since=t0):
        if w.t > t_end:
            break  # the safe stop on the way out
        assert w.id in by_id, f"a write reached servo {w.id}: {w}"
        assert w.value("torque_enable") in (None, 1), f"torque changed uncommanded: {w}"
        goal = w.value("goal_position")
        if goal is None:
            continue
        assert any(t <= w.t for t in goes), f"an arm goal no accepted command asked for: {w}"
        g = by_id[w.id]
        lo, hi = g.window_rad
        rad = g.counts_to_rad(goal)
        assert lo - tolerance <= rad <= hi + tolerance, f"{g.name} goal {rad:.3f} rad outside"


# -- what the fuzzing found, pinned -----------------------------------------------------------


async def test_a_pose_go_too_slow_to_stream_is_refused_and_the_tick_runs_on(
    sim: Sim, http: aiohttp.ClientSession
) -> None:
    """Was: speed_rad_s 1e-12 asked for billions of setpoints and froze the event loop."""
    async with running_daemon(sim) as daemon, running_api(daemon) as api:
        assert (await post(http, api.url + "/api/arm/torque", {"enabled": True}))[0] == 200
        async with http.put(
            api.url + "/api/arm/poses/near", json={"joints_rad": {"elbow_flex": 0.1}}
        ) as resp:
            assert resp.status == 200
        t0 = time.monotonic()
        async with asyncio.timeout(2.0):
            status, body = await post(
                http, api.url + "/api/arm/poses/near/go", {"speed_rad_s": 1e-12}
            )
        assert status == 400 and "speed_rad_s" in body["error"]["message"], body
        await assert_still_ticking(sim, daemon)
        assert not [w for w in sim.bus.writes(since=t0) if w.value("goal_position") is not None]


async def test_an_empty_pose_is_refused_by_name_not_a_500(
    sim: Sim, http: aiohttp.ClientSession, lupin_home: Path
) -> None:
    """Was: PUT {"joints_rad": {}} was stored, and going to it answered 500 (empty trajectory)."""
    async with running_daemon(sim) as daemon, running_api(daemon) as api:
        async with http.put(api.url + "/api/arm/poses/none", json={"joints_rad": {}}) as resp:
            assert resp.status == 400
            assert "joints_rad" in (await resp.json())["error"]["message"]
        # A hand-edited file can still hold one: going to it is a clear 409.
        (lupin_home / "poses.yaml").write_text("poses:\n  none: {}\n")
        t0 = time.monotonic()
        status, body = await post(http, api.url + "/api/arm/poses/none/go", {})
        assert (status, body["error"]["code"]) == (409, "empty_pose"), body
        assert "none" in body["error"]["message"]
        assert_nothing_written(sim, t0, "going to an empty pose")
        await assert_still_ticking(sim, daemon)
