"""Entry point of the ``lupin`` command (console script and ``python -m lupin``).

Each subcommand lives in its own module and is imported only when run, so
``lupin --help`` works even where an optional adapter's library is missing.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from lupin.cli.parser import parse_args
from lupin.config import ConfigError
from lupin.logs import setup_logging

# command -> "module:function"; a command missing here has not landed yet.
HANDLERS: dict[str, str] = {
    "run": "lupin.cli.run:main",
    "sim": "lupin_adapters.sim.cli:main",
    "check": "lupin.cli.check:main",
    "calibrate": "lupin.cli.calibrate:main",
    "offsets": "lupin.cli.offsets:main",
    "gains": "lupin.cli.gains:main",
    "pad-calibrate": "lupin.cli.pad_calibrate:main",
    "pad-record": "lupin.cli.pad_record:main",
    "bt-fix": "lupin.cli.bt_fix:main",
    "stop-helper": "lupin.cli.stop_helper:main",
    "install-service": "lupin.cli.install_service:main",
    "heal": "lupin.cli.heal:main",
    "pose": "lupin.cli.pose:main",
    "jog": "lupin.cli.jog:main",
}

# What is still to come, said plainly rather than faked.
PENDING: dict[str, str] = {
    "run": "the daemon (issue: the daemon)",
    "sim": "the simulated bus (issue: the Feetech bus)",
}

EXIT_NOT_AVAILABLE = 3


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    setup_logging(getattr(args, "log_level", "info"))
    return dispatch(args)


def dispatch(args: argparse.Namespace) -> int:
    target = HANDLERS.get(args.command)
    if target is None:
        what = PENDING.get(args.command, "this command")
        print(f"lupin {args.command}: not available yet; it lands with {what}.", file=sys.stderr)
        return EXIT_NOT_AVAILABLE
    module_name, func_name = target.split(":")
    func = getattr(importlib.import_module(module_name), func_name)
    try:
        return int(func(args))
    except ConfigError as exc:
        print(f"lupin {args.command}: configuration error:\n{exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
