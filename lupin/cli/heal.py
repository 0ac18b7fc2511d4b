"""``lupin heal``: re-run heal and auto-home on the running daemon, over its API.

Exit codes follow the heal tri-state: healthy, healed and unknown exit 0
(unknown means the bus could not be enumerated, and a non-zero exit under a
systemd ``Restart=on-failure`` would be the runbook's retry storm); failed
exits 1. A daemon that is not running, or refuses the token, gets a clear
message and a sysexits code (69 unavailable, 77 no permission).
"""

from __future__ import annotations

import argparse
import asyncio
import sys

from lupin.api.client import ApiClient, ApiClientError
from lupin.api_models import HealResponse


async def request_heal(url: str | None, token: str | None) -> HealResponse:
    async with ApiClient(url, token) as client:
        return HealResponse.model_validate(await client.request("POST", "/api/heal"))


def report(reply: HealResponse) -> int:
    print(f"heal: {reply.result}")
    for line in reply.details:
        print(f"  {line}")
    if reply.auto_home is not None:
        print(f"auto-home: {reply.auto_home}")
    return 1 if reply.result == "failed" else 0


def main(args: argparse.Namespace) -> int:
    try:
        reply = asyncio.run(request_heal(args.url, args.token))
    except ApiClientError as exc:
        print(f"lupin heal: {exc}", file=sys.stderr)
        return exc.exit_code
    return report(reply)
