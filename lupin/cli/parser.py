"""The ``lupin`` command line: every subcommand of SPEC §6, parsed strictly.

Strict means a mistyped flag is an error (exit 2) and never a silent default:
the bring-up seed's `--max-travel` typo moved the arm under the default. So
abbreviations are off on every parser and unknown arguments are refused.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

from lupin import __version__
from lupin.logs import LEVELS

PAD_LAYOUTS = ("xbox-usb", "xbox-bluetooth", "ds4")


def _finite_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"not a finite number: {text!r}")
    return value


def _positive_float(text: str) -> float:
    value = _finite_float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be above 0: {text!r}")
    return value


def _port_number(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"port out of range 0-65535: {text!r}")
    return value


def _pad_spec(text: str) -> str:
    if text in ("auto", "none"):
        return text
    kind, sep, rest = text.partition(":")
    if not sep or not rest or kind not in ("evdev", "hid", "replay"):
        raise argparse.ArgumentTypeError(
            f"bad pad {text!r}: use auto, none, evdev:DEVICE, hid:VID:PID or replay:FILE"
        )
    if kind == "hid":
        vid, sep2, pid = rest.partition(":")
        try:
            int(vid, 16), int(pid, 16)
        except ValueError:
            raise argparse.ArgumentTypeError(f"bad hid id {rest!r}: use hex VID:PID") from None
        if not sep2:
            raise argparse.ArgumentTypeError(f"bad hid id {rest!r}: use hex VID:PID")
    return text


def _id_range(text: str) -> range:
    first, sep, last = text.partition("-")
    try:
        lo, hi = int(first), int(last) if sep else int(first)
    except ValueError:
        raise argparse.ArgumentTypeError(f"bad id range {text!r}: use FIRST-LAST") from None
    if not 0 <= lo <= hi <= 253:
        raise argparse.ArgumentTypeError(f"bad id range {text!r}: ids are 0-253, first <= last")
    return range(lo, hi + 1)


def _gain_list(text: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"bad gain list {text!r}: use e.g. 16,32,64") from None
    if not all(0 <= v <= 254 for v in values):
        raise argparse.ArgumentTypeError(f"gains are 0-254: {text!r}")
    return values


def _gain_speed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if not 1 <= value <= 3000:
        raise argparse.ArgumentTypeError(f"speed must be 1-3000 counts/s: {text!r}")
    return value


def _joint_counts(text: str) -> tuple[str, int]:
    name, sep, value = text.partition("=")
    try:
        if not sep or not name:
            raise ValueError
        return name, int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"bad {text!r}: use JOINT=COUNTS") from None


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--log-level", choices=LEVELS, default="info", help="logging level")


def _robot(p: argparse.ArgumentParser) -> None:
    """Flags of every command that loads a profile and opens the bus."""
    p.add_argument("--profile", help="robot profile name or YAML path (default so101)")
    p.add_argument("--config", help="site config YAML merged over the profile")
    p.add_argument("--bus-port", help="serial device, overriding the profile's (e.g. a sim pty)")
    p.add_argument("--yes", action="store_true", help="answer yes to every prompt (scripts)")


def _client(p: argparse.ArgumentParser) -> None:
    """Flags of every command that talks to the running daemon's API."""
    p.add_argument("--url", default=None, help="daemon URL (default http://127.0.0.1:8080)")
    p.add_argument("--token", default=None, help="API token (default $LUPIN_TOKEN)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="lupin", description="Lupin robot daemon and bench tools.")
    parser.add_argument("--version", action="version", version=f"lupin {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    run = sub.add_parser("run", help="run the daemon")
    _common(run)
    run.add_argument("--sim", action="store_true", help="drive the built-in simulated robot")
    run.add_argument("--profile")
    run.add_argument("--config")
    run.add_argument("--bus-port")
    run.add_argument("--host")
    run.add_argument("--port", type=_port_number)
    run.add_argument("--pad", type=_pad_spec, default="auto")
    run.add_argument("--pad-layout", choices=PAD_LAYOUTS)

    sim = sub.add_parser("sim", help="serve the profile's simulated servos on a pty")
    _common(sim)
    sim.add_argument("--profile")
    sim.add_argument("--config")
    sim.add_argument("--wire-pacing", action="store_true", help="pace replies at the wire rate")

    check = sub.add_parser("check", help="enumerate servos, health and zero snapshot")
    _common(check)
    _robot(check)
    check.add_argument(
        "--scan", type=_id_range, default=range(0, 21), help="ids to scan for strays (default 0-20)"
    )

    cal = sub.add_parser("calibrate", help="two-phase range and zero calibration")
    _common(cal)
    _robot(cal)
    cal.add_argument("--margin", type=_positive_float, default=0.05)
    cal.add_argument("--skip-homing", action="store_true")
    cal.add_argument("--joints", help="comma-separated joints to redo")

    offsets = sub.add_parser(
        "offsets",
        help="servo homing offsets: show|backup|restore|set|export-lerobot|import-lerobot",
    )
    actions = offsets.add_subparsers(dest="action", metavar="ACTION", parser_class=_Parser)
    actions.required = True
    for name, text in (
        ("show", "read every arm servo's homing offset"),
        ("backup", "snapshot the offsets to the backup file"),
        ("restore", "write the backup file's offsets back, verified"),
        ("set", "write offsets by hand: JOINT=COUNTS ..."),
        ("export-lerobot", "write the calibration as LeRobot's per-motor JSON"),
        ("import-lerobot", "write a LeRobot calibration JSON to the servos and arm.yaml"),
    ):
        action = actions.add_parser(name, help=text)
        _common(action)
        _robot(action)
        if name in ("backup", "restore"):
            action.add_argument(
                "--file", help="backup file (default $LUPIN_HOME/arm_offsets_backup.yaml)"
            )
        if name == "set":
            action.add_argument("values", nargs="+", type=_joint_counts, metavar="JOINT=COUNTS")
        if name in ("export-lerobot", "import-lerobot"):
            action.add_argument("file", help="LeRobot calibration JSON")
        if name == "import-lerobot":
            action.add_argument(
                "--margin",
                type=_positive_float,
                default=0.05,
                help="rad the soft limits sit inside LeRobot's recorded stops (default 0.05)",
            )

    gains = sub.add_parser("gains", help="servo PID gains: show|apply|sweep")
    gain_actions = gains.add_subparsers(dest="action", metavar="ACTION", parser_class=_Parser)
    gain_actions.required = True
    for name, text in (
        ("show", "compare servo EEPROM gains with the profile (read-only)"),
        ("apply", "write the profile's gains, verified by a double read-back"),
    ):
        action = gain_actions.add_parser(name, help=text)
        _common(action)
        _robot(action)
        action.add_argument("--joints", help="comma-separated joints (default: every arm joint)")
    sweep = gain_actions.add_parser("sweep", help="step one joint under each candidate gain set")
    _common(sweep)
    _robot(sweep)
    sweep.add_argument("--joint", required=True)
    sweep.add_argument("--kp", type=_gain_list, default=[16, 32, 64, 128], help="e.g. 16,32,64")
    sweep.add_argument("--ki", type=_gain_list, default=[0], help="e.g. 0,1,2")
    sweep.add_argument("--step", type=_finite_float, default=-0.2, help="rad (default -0.2)")
    sweep.add_argument("--max-temp", type=_positive_float, default=55.0, help="°C (default 55)")
    sweep.add_argument("--speed", type=_gain_speed, default=500, help="counts/s (default 500)")
    sweep.add_argument("--hold", type=_positive_float, default=1.5, help="s sampled per step")

    pose = sub.add_parser("pose", help="taught poses (client of the daemon)")
    _common(pose)
    _client(pose)
    pose.add_argument("action", choices=("save", "list", "go", "limits", "delete"))
    pose.add_argument("name", nargs="?")
    pose.add_argument("--max-travel", type=_positive_float, default=0.35)
    pose.add_argument("--speed", type=_positive_float, default=0.5)
    pose.add_argument("--yes", action="store_true")

    jog = sub.add_parser("jog", help="interactive per-joint jog (client of the daemon)")
    _common(jog)
    _client(jog)
    jog.add_argument("--step", type=_positive_float, default=0.05)

    heal = sub.add_parser("heal", help="re-run heal and auto-home on the running daemon")
    _common(heal)
    _client(heal)

    padcal = sub.add_parser("pad-calibrate", help="probe a pad's mapping interactively")
    _common(padcal)
    padcal.add_argument("--pad", type=_pad_spec, default="auto")
    padcal.add_argument("--pad-layout", choices=PAD_LAYOUTS)
    padcal.add_argument("--mapping-dir", help="where mapping files live")

    padrec = sub.add_parser("pad-record", help="record raw pad frames to a JSON-lines file")
    _common(padrec)
    padrec.add_argument("file")
    padrec.add_argument("--pad", type=_pad_spec, default="auto")
    padrec.add_argument("--seconds", type=_positive_float)

    bt = sub.add_parser("bt-fix", help="pin BlueZ LE connection intervals for the Xbox pad")
    _common(bt)
    bt.add_argument("--main-conf", default="/etc/bluetooth/main.conf")
    bt.add_argument("--device", help="pad MAC address whose stale bond to remove")
    bt.add_argument("--dry-run", action="store_true")

    stop = sub.add_parser(
        "stop-helper", help="zero the wheels and limp every servo after a crash (ExecStopPost)"
    )
    _common(stop)
    stop.add_argument("--profile", help="robot profile name or YAML path (default so101)")
    stop.add_argument("--config", help="site config YAML merged over the profile")
    stop.add_argument("--bus-port", help="serial device, overriding the profile's")
    stop.add_argument("--timeout", type=_positive_float, default=3.0, help="s overall (default 3)")

    inst = sub.add_parser("install-service", help="install the systemd unit, udev rule and config")
    _common(inst)
    inst.add_argument("--dry-run", action="store_true", help="print every action, write nothing")
    inst.add_argument("--user", help="user the daemon runs as (default: $SUDO_USER)")
    inst.add_argument("--prefix", help="venv or prefix holding bin/lupin (default: this one)")
    inst.add_argument("--profile", default="so101", help="profile for a new site config")
    inst.add_argument("--root", default="/", help="install under this directory (default /)")

    parser.set_defaults(_subparsers=sub.choices)
    return parser


def parse_args(argv: Any = None) -> argparse.Namespace:
    """Parse strictly; an unknown flag is reported with its subcommand's usage (exit 2)."""
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    subparsers = args.__dict__.pop("_subparsers")
    if extra:
        subparsers[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
    return args
