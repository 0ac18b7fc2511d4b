"""``lupin pad-record FILE [--pad SPEC] [--seconds S]``: record raw pad frames.

The file is a replay file (JSON lines, ``t`` from the start of the recording),
so what a pad did on the day can be replayed into the daemon with
``--pad replay:FILE``, for tests, demos and bug reports.
"""

from __future__ import annotations

import argparse
import asyncio
import sys

from lupin import registry
from lupin.pad import JOYSTICK_GROUP, open_pad
from lupin.pad_mapping import resolve_layout


def main(args: argparse.Namespace) -> int:
    layout = resolve_layout(getattr(args, "pad_layout", None))
    try:
        reader = open_pad(args.pad, layout=layout)
        recorder = registry.load(JOYSTICK_GROUP, "replay")
    except (registry.AdapterNotFound, ValueError) as exc:
        print(f"lupin pad-record: {exc}", file=sys.stderr)
        return 2
    if reader is None:
        print("lupin pad-record: --pad none records nothing", file=sys.stderr)
        return 2
    until = f"for {args.seconds:g} s" if args.seconds else "until Ctrl-C"
    print(f"recording {reader.name} (layout {layout}) to {args.file} {until}", flush=True)
    try:
        count = asyncio.run(recorder.record(reader, args.file, args.seconds))
    except KeyboardInterrupt:
        print(f"\nstopped; {args.file} keeps every frame recorded so far")
        return 0
    print(f"wrote {count} frames to {args.file}")
    return 0
