"""``lupin bt-fix``: pin BlueZ's LE connection intervals for the Xbox pad over BLE.

Why (runbook, "The Xbox BLE pairing trap"): without a pin, BlueZ accepts the
pad's suggested MinInterval=6 (7.5 ms), the GATT HID descriptor read fails and
the connection loops every ~4 s: the light blinks forever, no
/dev/input/event* appears, teleop is dead. Pinning ``[LE]
MinConnectionInterval=7, MaxConnectionInterval=9, ConnectionLatency=0``
(8.75-11.25 ms, the pad's 100 Hz protocol) fixes it, after a bluetooth restart
and the removal of the stale LE bond, which otherwise keeps the old intervals.

The edit touches only those three keys in ``[LE]`` (a commented default like
``#MinConnectionInterval=`` becomes the set value), keeps everything else,
backs up ``main.conf.bak`` first, and is idempotent.
"""

from __future__ import annotations

import argparse
import difflib
import re
import shutil
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

PINS = (("MinConnectionInterval", "7"), ("MaxConnectionInterval", "9"), ("ConnectionLatency", "0"))
SECTION = "LE"
MAC = re.compile(r"^[0-9A-Fa-f]{2}(:[0-9A-Fa-f]{2}){5}$")
_HEADER = re.compile(r"^\s*\[([^\]]+)\]\s*$")

Runner = Callable[[Sequence[str]], int]


def _run(cmd: Sequence[str]) -> int:
    return subprocess.run(list(cmd), check=False).returncode


def pin_le_intervals(text: str) -> str:
    """Return ``text`` with the three [LE] keys pinned; unchanged if already pinned."""
    lines = text.splitlines(keepends=True)
    if lines and not lines[-1].endswith("\n"):
        lines[-1] += "\n"
    start = next((i for i, ln in enumerate(lines) if _is_header(ln, SECTION)), None)
    if start is None:
        block = [f"[{SECTION}]\n", *(f"{k}={v}\n" for k, v in PINS)]
        gap = ["\n"] if lines and lines[-1].strip() else []
        return "".join(lines + gap + block) if lines else "".join(block)
    end = next((i for i in range(start + 1, len(lines)) if _HEADER.match(lines[i])), len(lines))
    for key, value in PINS:
        active = re.compile(rf"^\s*{key}\s*=\s*(.*?)\s*$")
        commented = re.compile(rf"^\s*#\s*{key}\s*=")
        hits = [i for i in range(start + 1, end) if active.match(lines[i])]
        for i in hits:
            match = active.match(lines[i])
            if match is not None and match.group(1) != value:
                lines[i] = f"{key}={value}\n"
        if hits:
            continue
        commented_at = next((i for i in range(start + 1, end) if commented.match(lines[i])), None)
        if commented_at is not None:
            lines[commented_at] = f"{key}={value}\n"
            continue
        # After the section's last non-blank line, so a blank separator stays last.
        at = end
        while at > start + 1 and not lines[at - 1].strip():
            at -= 1
        lines.insert(at, f"{key}={value}\n")
        end += 1
    return "".join(lines)


def _is_header(line: str, name: str) -> bool:
    match = _HEADER.match(line)
    return match is not None and match.group(1).strip() == name


def fix(
    conf: Path,
    *,
    device: str | None = None,
    dry_run: bool = False,
    runner: Runner = _run,
    which: Callable[[str], str | None] = shutil.which,
    out: Callable[[str], None] = print,
) -> int:
    """Pin, back up, restart bluetooth, remove the stale bond. Returns an exit code."""
    if device is not None and not MAC.match(device):
        out(f"bt-fix: --device {device!r} is not a MAC address (AA:BB:CC:DD:EE:FF)")
        return 2
    try:
        old = conf.read_text(encoding="utf-8") if conf.exists() else ""
    except OSError as exc:
        out(f"bt-fix: cannot read {conf}: {exc}")
        return 1
    new = pin_le_intervals(old)
    changed = new != old
    if not changed:
        out(f"{conf}: [LE] intervals already pinned; nothing to change")
    elif dry_run:
        diff = difflib.unified_diff(
            old.splitlines(keepends=True), new.splitlines(keepends=True), str(conf), str(conf)
        )
        out("".join(diff).rstrip("\n"))
        out("dry run: nothing written")
    else:
        try:
            if conf.exists():
                backup = conf.with_name(conf.name + ".bak")
                shutil.copy2(conf, backup)
                out(f"backed up {conf} to {backup}")
            conf.write_text(new, encoding="utf-8")
        except OSError as exc:
            out(f"bt-fix: cannot write {conf}: {exc} (run with sudo?)")
            return 1
        out(f"{conf}: pinned [LE] " + ", ".join(f"{k}={v}" for k, v in PINS))
    failed = False
    steps: list[tuple[list[str], str]] = []
    if changed:
        steps.append((["systemctl", "restart", "bluetooth"], "restart bluetooth"))
    if device is not None:
        # The stale LE bond locks in the old intervals until it is removed.
        steps.append((["bluetoothctl", "remove", device], f"remove the stale bond of {device}"))
    for cmd, what in steps:
        if dry_run:
            out(f"dry run: would {what}: {' '.join(cmd)}")
        elif which(cmd[0]) is None:
            out(f"skipped: cannot {what}: {cmd[0]} not found; run `{' '.join(cmd)}` yourself")
        else:
            code = runner(cmd)
            out(f"{' '.join(cmd)}: {'ok' if code == 0 else f'failed (exit {code})'}")
            failed = failed or code != 0
    if changed and not dry_run:
        out("now re-pair the pad: bluetoothctl scan on, pair, trust, connect")
    return 1 if failed else 0


def main(args: argparse.Namespace) -> int:
    return fix(Path(args.main_conf), device=args.device, dry_run=args.dry_run, out=_print)


def _print(text: str) -> None:
    print(text, file=sys.stdout, flush=True)
