"""What the API-client commands (``lupin pose``, ``lupin jog``) share: exits, reads, units.

They are clients of the running daemon and never open the bus: the daemon owns
it, and the bring-up seed has ``arm-pose go`` and ``jog`` run "happily
alongside a mission" for exactly that reason. Exit codes follow ``lupin heal``:
0 done, 1 refused or not found, 2 usage, 69 no daemon, 75 no answer in time,
77 token missing or wrong.
"""

from __future__ import annotations

import asyncio
import math
import sys
from collections.abc import Awaitable, Callable, Iterable, Mapping

from pydantic import ValidationError

from lupin import api_models as m
from lupin.api.client import EXIT_UNAVAILABLE, ApiClient, ApiClientError

EXIT_OK = 0
EXIT_FAILED = 1  # refused by the daemon, declined at the prompt, or not found
EXIT_USAGE = 2


class UsageError(Exception):
    """A bad argument found after parsing (a missing pose name); exit 2, nothing sent."""


def run_client(
    command: str, url: str | None, token: str | None, body: Callable[[ApiClient], Awaitable[int]]
) -> int:
    """Run ``body`` with a connected client; every failure is one line on stderr and an exit."""

    async def guarded() -> int:
        async with ApiClient(url, token) as client:
            return await body(client)

    try:
        return asyncio.run(guarded())
    except UsageError as exc:
        print(f"lupin {command}: {exc}", file=sys.stderr, flush=True)
        return EXIT_USAGE
    except ApiClientError as exc:
        print(f"lupin {command}: {exc}", file=sys.stderr, flush=True)
        return exc.exit_code
    except ValidationError as exc:
        # A 2xx whose body is not what this version expects: a different daemon.
        print(
            f"lupin {command}: the daemon's answer is not what this client understands "
            f"(a different Lupin version?): {exc.errors()[0]['msg']}",
            file=sys.stderr,
            flush=True,
        )
        return EXIT_UNAVAILABLE


async def get_robot(client: ApiClient) -> m.RobotInfo:
    return m.RobotInfo.model_validate(await client.request("GET", "/api/robot"))


async def get_state(client: ApiClient) -> m.RobotState:
    return m.RobotState.model_validate(await client.request("GET", "/api/state"))


def ordered(names: Iterable[str], robot: m.RobotInfo) -> list[str]:
    """``names`` in the robot's joint order; anything the robot does not list goes last."""
    rank = {j.name: k for k, j in enumerate(robot.joints)}
    return sorted(set(names), key=lambda n: (rank.get(n, len(rank)), n))


def deg(rad: float) -> str:
    return f"{math.degrees(rad):.1f}"


def table(header: list[str], rows: list[list[str]]) -> str:
    """Left-aligned first column, the rest right-aligned: names then numbers."""
    widths = [max(len(r[k]) for r in [header, *rows]) for k in range(len(header))]
    lines = []
    for row in [header, *rows]:
        cells = [row[0].ljust(widths[0])] + [
            c.rjust(w) for c, w in zip(row[1:], widths[1:], strict=True)
        ]
        lines.append("  ".join(cells).rstrip())
    return "\n".join(lines)


def not_torqued(state: m.RobotState, joints: Iterable[str]) -> list[str]:
    """Those of ``joints`` whose torque is not on (off, unknown or still enabling)."""
    by_name: Mapping[str, m.JointState] = {j.name: j for j in state.joints}
    return [n for n in joints if n in by_name and by_name[n].torque != "on"]
