"""``lupin sim``: serve a profile's simulated servos on a pty until interrupted.

The first line printed is the pty's path, so a script can start the simulator
and hand that path to ``lupin run --bus-port`` or to any bench tool.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import signal
import sys

from lupin.config import load_profile
from lupin_adapters.sim.bus import build_sim_bus
from lupin_adapters.sim.link import sim_specs
from lupin_adapters.sim.pty_server import PtySimServer


def main(args: argparse.Namespace) -> int:
    profile = load_profile(args.profile, config_file=args.config)
    return asyncio.run(_serve(profile.bus.baud, sim_specs(profile), args.wire_pacing))


async def _serve(baud: int, specs: list, wire_pacing: bool) -> int:  # type: ignore[type-arg]
    server = PtySimServer(build_sim_bus(specs), baud=baud, wire_pacing=wire_pacing)
    path = await server.start()
    print(path, flush=True)
    print(f"simulating servo ids {[s.id for s in specs]}; Ctrl-C to stop", file=sys.stderr)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    with contextlib.suppress(asyncio.CancelledError):
        await stop.wait()
    await server.close()
    return 0
