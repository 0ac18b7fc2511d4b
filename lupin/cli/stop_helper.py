"""``lupin stop-helper``: what ``lupin.service`` runs as ``ExecStopPost``.

Zeroes the wheels and limps every servo of the profile when the daemon died
without doing it (see ``lupin/stop_helper.py``). It always exits 0: a failing
ExecStopPost would turn a clean stop into a failed unit, and there is nothing
left for systemd to do about a bus it cannot reach. What happened goes to the
journal instead.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import math
import os
import signal
import tempfile
from pathlib import Path
from types import FrameType

from lupin.config import ConfigError, load_profile
from lupin.config_models import RobotProfile
from lupin.stop_helper import clean_exit, describe_exit, run_stop_helper

log = logging.getLogger("lupin.stop_helper")

# Past the asyncio deadline, a last resort: a wedged USB-serial adapter can block
# the close() syscall itself (tty drain), where no coroutine timeout reaches.
BACKSTOP_EXTRA_S = 2


def _backstop(_signum: int, _frame: FrameType | None) -> None:
    os.write(2, b"lupin stop-helper: still blocked past its deadline; giving up\n")
    os._exit(0)


def main(args: argparse.Namespace) -> int:
    env = dict(os.environ)
    how = describe_exit(env)
    if clean_exit(env):
        log.info("daemon exited cleanly (%s): it limped the robot itself; nothing to do", how)
        return 0
    previous = signal.signal(signal.SIGALRM, _backstop)
    signal.alarm(math.ceil(args.timeout) + BACKSTOP_EXTRA_S)
    try:
        return _limp(args, env, how)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def _profile(args: argparse.Namespace) -> RobotProfile:
    try:
        return load_profile(args.profile, config_file=args.config)
    except ConfigError as exc:
        # Ids, baud and port never come from the measured overlay ($LUPIN_HOME/arm.yaml):
        # a broken calibration file must not stop the limp.
        log.warning("%s; trying again without the calibration overlay", exc)
        with tempfile.TemporaryDirectory() as empty:
            return load_profile(args.profile, config_file=args.config, home=Path(empty))


def _limp(args: argparse.Namespace, env: dict[str, str], how: str) -> int:
    try:
        profile = _profile(args)
    except ConfigError as exc:
        log.error("cannot load the profile, so cannot limp the robot: %s", exc)
        return 0
    port = args.bus_port or profile.bus.port
    log.warning("daemon ended (%s): zeroing wheels and limping every servo on %s", how, port)
    report = asyncio.run(run_stop_helper(profile, port, env=env, timeout=args.timeout))
    level = logging.INFO if report.action == "limped" and not report.still_on else logging.ERROR
    log.log(level, "%s", report.summary())
    return 0
