"""``lupin run``: load the profile, start the daemon, stop it safely on a signal."""

from __future__ import annotations

import argparse
import asyncio
import gc
import logging
import signal
import sys
from typing import Any

from lupin.api import ApiServer
from lupin.config import load_profile
from lupin.daemon import BusOpenError, Daemon, DaemonOptions, PadError
from lupin.sdnotify import SdNotifier, WatchdogPinger, announce_ready, watchdog_interval

log = logging.getLogger("lupin.run")

# Exit code when the bus cannot be opened (nothing was sent to any servo).
EXIT_BUS = 4
# Exit code when the wheels-zero / torque-off sequence could not be sent on the way out.
EXIT_UNSAFE_STOP = 6
# Exit code when the API cannot listen (port taken, bad TLS files); the arm was left limp.
EXIT_API = 5


def overrides_from(args: argparse.Namespace) -> dict[str, Any]:
    api: dict[str, Any] = {}
    if args.host is not None:
        api["host"] = args.host
    if args.port is not None:
        api["port"] = args.port
    return {"api": api} if api else {}


def main(args: argparse.Namespace) -> int:
    profile = load_profile(args.profile, config_file=args.config, overrides=overrides_from(args))
    options = DaemonOptions(
        sim=args.sim, bus_port=args.bus_port, pad=args.pad, pad_layout=args.pad_layout
    )
    return asyncio.run(serve(Daemon(profile, options), args))


async def serve(daemon: Daemon, args: argparse.Namespace) -> int:
    """Run until SIGTERM/SIGINT, then the safe stop.

    The start-up heap (imports, profile, tables, the API's routes) is frozen out
    of the garbage collector: a full collection walks every tracked object, and
    over the ~50 MB start-up heap that measured 13-16 ms, longer than a 10 ms
    tick, so every few minutes a tick slipped. Frozen objects are never walked
    again; later collections see only what the running daemon allocated.
    """
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    try:
        pad = daemon.prepare_pad()
    except PadError as exc:
        print(f"lupin run: pad: {exc}", file=sys.stderr)
        return 2
    # Before the tick exists, so this one full collection delays nothing.
    gc.collect()
    gc.freeze()
    try:
        await daemon.start()
    except BusOpenError as exc:
        print(f"lupin run: {exc}", file=sys.stderr)
        return EXIT_BUS
    try:
        api = ApiServer(daemon.services, daemon.profile.api)
        url = await api.start()
    except (OSError, ValueError) as exc:
        print(
            f"lupin run: cannot serve the API on {daemon.profile.api.host}:"
            f"{daemon.profile.api.port}: {exc}",
            file=sys.stderr,
        )
        await daemon.stop()
        return EXIT_API
    log.info("API listening on %s%s", url, " (token required)" if api.token else "")
    # The port really opened: --bus-port overrides the profile's, and the journal's
    # "ready" line is what an operator checks to see which bus the daemon owns.
    where = (
        "simulated bus"
        if daemon.options.sim
        else daemon.options.bus_port or daemon.profile.bus.port
    )
    notifier = SdNotifier.from_env()  # None unless run by systemd as Type=notify
    announcer: asyncio.Task[None] | None = None
    if notifier is not None:
        interval = watchdog_interval()
        if interval is not None and daemon.loop is not None:
            # Pinged from the control tick itself: a stalled tick stops the pings.
            daemon.loop.on_tick.append(WatchdogPinger(notifier, interval).on_tick)
        status = f"ready: {daemon.profile.name} on {where}"
        announcer = asyncio.create_task(announce_ready(notifier, daemon.wait_ready, status))
    safe = False
    try:
        ready = await daemon.wait_ready(5.0)
        # What start-up built lives as long as the daemon: stop walking it (see below).
        gc.freeze()
        if ready:
            log.info("ready: %s on %s, arm limp", daemon.profile.name, where)
        else:
            log.warning("no complete joint state yet on %s; still trying", where)
        if pad is not None:
            daemon.start_pad(pad)  # after ready: a replay's t counts from here
        await stop.wait()
        log.info("stopping on signal")
    finally:
        if announcer is not None:
            announcer.cancel()
        if notifier is not None:
            notifier.stopping("stopping: zeroing wheels, limping the arm")
        await api.stop()  # no request may reach a daemon that is shutting down
        safe = await daemon.stop()
    # Non-zero when the safe stop could not be sent, so ExecStopPost's helper runs.
    return 0 if safe else EXIT_UNSAFE_STOP
