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

# command -> "module:function", imported only when that command runs (a fast `--help`).
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


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    setup_logging(getattr(args, "log_level", "info"))
    return dispatch(args)


def dispatch(args: argparse.Namespace) -> int:
    module_name, func_name = HANDLERS[args.command].split(":")
    func = getattr(importlib.import_module(module_name), func_name)
    try:
        return int(func(args))
    except ConfigError as exc:
        print(f"lupin {args.command}: configuration error:\n{exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
