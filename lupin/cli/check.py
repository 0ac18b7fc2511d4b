"""``lupin check``: who answers on the bus, how each servo is, and the zero snapshot. Read-only.

Exit 0 when every profile servo answers, 1 otherwise, 4 if the bus cannot be
opened (another process holds it: the message names its PID).
"""

from __future__ import annotations

import argparse

from lupin.bench.health import CheckReport, ServoHealth, run_check
from lupin.bench.registers import ServoIO
from lupin.bench.session import open_bench_bus
from lupin.cli.bench_io import EXIT_FAILED, EXIT_OK, Terminal, load, port_of, run_tool

HEADER = (
    f"{'id':>3}  {'name':<14} {'kind':<5} {'fw':>5} {'model':>5} {'mode':>4} {'torque':>6} "
    f"{'volt':>5} {'temp':>5} {'load':>5} {'offset':>6} {'limits':>11}"
)


def main(args: argparse.Namespace) -> int:
    profile = load(args)
    term = Terminal(args.yes)
    port = port_of(args, profile)

    async def body() -> int:
        async with open_bench_bus(profile, args.bus_port) as bus:
            report = await run_check(ServoIO(bus), profile, args.scan)
        term.say(f"lupin check: {profile.name} on {port} ({profile.bus.baud} baud)\n")
        for line in render(report):
            term.say(line)
        return EXIT_OK if report.ok else EXIT_FAILED

    return run_tool("check", body)


def render(report: CheckReport) -> list[str]:
    lines = [HEADER]
    lines += [_row(s) for s in report.servos]
    problems = [(s, p) for s in report.servos for p in s.problems]
    if problems:
        lines.append("")
        lines += [f"  ! {s.name} (id {s.id}): {p}" for s, p in problems]
    scanned = f"{report.scanned.start}-{report.scanned.stop - 1}" if report.scanned else "none"
    strays = ", ".join(str(i) for i in report.strays) or "none"
    lines.append(f"\nstrays (ids {scanned} not in the profile): {strays}")
    lines.append("\nzero snapshot (present position, counts and rad about each joint's zero):")
    for s in report.servos:
        if s.kind == "arm":
            pos = s.registers.get("present_position")
            if pos is None or s.position_rad is None:
                lines.append(f"  {s.name:<14} no reading")
            else:
                lines.append(f"  {s.name:<14} {pos:>5} counts  {s.position_rad:+.4f} rad")
    answered = sum(s.answered for s in report.servos)
    lines.append(f"\n{answered} of {len(report.servos)} profile servos answer.")
    if report.missing:
        names = ", ".join(f"{s.name} (id {s.id})" for s in report.missing)
        lines.append(f"no reply from: {names}")
    return lines


def _row(s: ServoHealth) -> str:
    if not s.answered:
        return f"{s.id:>3}  {s.name:<14} {s.kind:<5} -- no reply --"
    r = s.registers

    def get(name: str, fmt: str = "{}") -> str:
        return fmt.format(r[name]) if name in r else "?"

    torque = {0: "off", 1: "on"}.get(s.torque, "?") if s.torque is not None else "?"
    volt = f"{r['present_voltage'] / 10:.1f}V" if "present_voltage" in r else "?"
    temp = get("present_temperature", "{}C")
    limits = (
        f"{r['min_position_limit']}-{r['max_position_limit']}" if "min_position_limit" in r else "?"
    )
    return (
        f"{s.id:>3}  {s.name:<14} {s.kind:<5} {s.firmware or '?':>5} {get('model'):>5} "
        f"{get('operating_mode'):>4} {torque:>6} {volt:>5} {temp:>5} {get('present_load'):>5} "
        f"{get('homing_offset'):>6} {limits:>11}"
    )
