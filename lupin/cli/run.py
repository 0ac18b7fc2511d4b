"""``lupin run``: load the profile, start the daemon, stop it safely on a signal."""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
from typing import Any

from lupin.config import load_profile
from lupin.daemon import BusOpenError, Daemon, DaemonOptions

log = logging.getLogger("lupin.run")

# Exit code when the bus cannot be opened (nothing was sent to any servo).
EXIT_BUS = 4


def overrides_from(args: argparse.Namespace) -> dict[str, Any]:
    api: dict[str, Any] = {}
    if args.host is not None:
        api["host"] = args.host
    if args.port is not None:
        api["port"] = args.port
    return {"api": api} if api else {}


def main(args: argparse.Namespace) -> int:
    profile = load_profile(args.profile, config_file=args.config, overrides=overrides_from(args))
    options = DaemonOptions(sim=args.sim, bus_port=args.bus_port)
    return asyncio.run(serve(Daemon(profile, options), args))


async def serve(daemon: Daemon, args: argparse.Namespace) -> int:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    try:
        await daemon.start()
    except BusOpenError as exc:
        print(f"lupin run: {exc}", file=sys.stderr)
        return EXIT_BUS
    try:
        ready = await daemon.wait_ready(5.0)
        where = "simulated bus" if daemon.options.sim else daemon.profile.bus.port
        if ready:
            log.info("ready: %s on %s, arm limp", daemon.profile.name, where)
        else:
            log.warning("no complete joint state yet on %s; still trying", where)
        await stop.wait()
        log.info("stopping on signal")
    finally:
        await daemon.stop()
    return 0
