"""``lupin gains show|apply|sweep``: reconcile servo EEPROM gains with the profile, or measure one.

``show`` is read-only (exit 1 when a servo differs); ``apply`` names every
EEPROM write, asks once, and reports success only on a double read-back that
agrees; ``sweep`` steps one joint under each candidate gain set, prints a
table and a one-line verdict, and saves every sample as JSON.
"""

from __future__ import annotations

import argparse
import asyncio

from lupin.bench.gain_sweep import (
    SweepRefused,
    SweepRun,
    SweepSettings,
    Trial,
    limp_joints,
    new_run,
    preflight,
    run_sweep,
    save_run,
)
from lupin.bench.gains import apply, compare
from lupin.bench.registers import ServoIO
from lupin.bench.session import open_bench_bus
from lupin.bench.step_response import TrialScore
from lupin.cli.bench_io import EXIT_FAILED, EXIT_OK, Terminal, load, run_tool, select_joints
from lupin.config import lupin_home
from lupin.config_models import RobotProfile
from lupin.joints import RAD_PER_COUNT

TABLE_HEADER = (
    f"{'Kp':>4} {'Ki':>3} {'error':>9} {'reached':>8} {'Kp*err':>7} {'load':>5} "
    f"{'settle':>7} {'ripple':>9} {'rev':>4}"
)


def main(args: argparse.Namespace) -> int:
    profile = load(args)
    term = Terminal(args.yes)
    action = {"show": show, "apply": apply_gains, "sweep": sweep}[args.action]
    return run_tool(f"gains {args.action}", lambda: action(args, profile, term))


async def show(args: argparse.Namespace, profile: RobotProfile, term: Terminal) -> int:
    joints = select_joints(profile, args.joints)
    async with open_bench_bus(profile, args.bus_port) as bus:
        rows = await compare(ServoIO(bus), joints)
    term.say(f"{'joint':<14} {'id':>3}  {'servo':<16} {'profile':<16}")
    for r in rows:
        have = str(r.have) if r.have else "unreadable"
        mark = "" if r.matches else "  differs"
        term.say(f"{r.name:<14} {r.id:>3}  {have:<16} {r.want!s:<16}{mark}")
    differ = [r for r in rows if not r.matches]
    term.say(f"{len(rows) - len(differ)} of {len(rows)} servos match the profile.")
    return EXIT_OK if not differ else EXIT_FAILED


async def apply_gains(args: argparse.Namespace, profile: RobotProfile, term: Terminal) -> int:
    joints = select_joints(profile, args.joints)
    async with open_bench_bus(profile, args.bus_port) as bus:
        io = ServoIO(bus)
        rows = await compare(io, joints)
        differ = [r for r in rows if not r.matches]
        if not differ:
            term.say("Every servo already holds the profile's gains; nothing to write.")
            return EXIT_OK
        term.say("EEPROM writes (registers 21-23, persistent):")
        for r in differ:
            have = str(r.have) if r.have else "unreadable"
            term.say(f"  {r.name} (id {r.id}): {have} -> {r.want}")
        if not await term.confirm("Write these gains?"):
            term.say("Nothing was written.")
            return EXIT_FAILED
        results = await apply(io, [j for j in joints if j.name in {r.name for r in differ}])
    for res in results:
        state = "ok" if res.ok else "FAILED"
        term.say(f"  {res.name} (id {res.id}) {res.want}: {state} ({res.detail})")
    return EXIT_OK if all(r.ok for r in results) else EXIT_FAILED


def score_row(s: TrialScore) -> str:
    settle = f"{s.settle_s:.2f} s" if s.settle_s is not None else "never"
    return (
        f"{s.kp:>4} {s.ki:>3} {s.error_rad:>5.3f} rad {s.reached:>8.1%} {s.kp_error:>7.2f} "
        f"{s.load:>5.0f} {settle:>7} {s.ripple_rad:>5.3f} rad {s.reversals:>4}"
    )


async def sweep(args: argparse.Namespace, profile: RobotProfile, term: Terminal) -> int:
    settings = SweepSettings(
        joint=args.joint,
        trials=[(kp, ki) for kp in args.kp for ki in args.ki],
        step_rad=args.step,
        max_temp=args.max_temp,
        speed=args.speed,
        hold_s=args.hold,
    )
    async with open_bench_bus(profile, args.bus_port) as bus:
        io = ServoIO(bus)
        try:
            plan = await preflight(io, profile, settings)
            if plan.others_torqued:
                names = ", ".join(plan.others_torqued)
                term.say(f"Only the swept joint may be torqued; {names} hold torque now.")
                if not await term.confirm(f"Release torque on {names}? (support the arm)"):
                    term.say("Nothing was changed.")
                    return EXIT_FAILED
                await limp_joints(io, profile, plan.others_torqued)
        except SweepRefused as exc:
            term.say(f"Refused: {exc}. Nothing was changed.")
            return EXIT_FAILED
        j = plan.joint
        term.say(
            f"Sweep {j.name} (id {j.id}): step {settings.step_rad:+.3f} rad "
            f"({plan.step_counts:+d} counts) from {plan.rest} to {plan.goal}, "
            f"{len(settings.trials)} trials (Kp {','.join(map(str, args.kp))} x Ki "
            f"{','.join(map(str, args.ki))}, D kept at {plan.original.d}), {plan.temperature} °C."
        )
        term.say(
            f"Each trial writes P/D/I to {j.name}'s EEPROM (registers 21-23) with torque off, "
            f"then torques only this joint; the joint goes limp between trials, so it must rest "
            f"where it holds unsupported. Its gains {plan.original} are written back at the end."
        )
        if not await term.confirm("Start the sweep?"):
            term.say("Nothing was changed.")
            return EXIT_FAILED
        run = new_run(plan, settings)
        term.say(TABLE_HEADER)

        def on_trial(index: int, trial: Trial) -> None:
            if trial.score is not None:
                term.say(score_row(trial.score))

        try:
            await run_sweep(io, run, on_trial=on_trial)
        except asyncio.CancelledError:
            report(run, term)
            raise
    return report(run, term)


def report(run: SweepRun, term: Terminal) -> int:
    """The verdict, the cleanup and where the samples went; the exit status."""
    if run.stopped:
        term.say(f"Stopped: {run.stopped}")
    term.say(run.verdict())
    c = run.cleanup
    where = (
        f"{c.returned_to} counts ({(c.returned_to - run.plan.rest) * RAD_PER_COUNT:+.3f} rad "
        f"from the start)"
        if c.returned_to is not None
        else "unknown"
    )
    term.say(
        f"Cleanup: joint at {where}; original gains {run.plan.original} "
        f"{'restored and verified' if c.gains_restored else 'NOT confirmed'}; "
        f"torque {'off' if c.torque_off else 'NOT confirmed off'}."
    )
    for note in c.notes:
        term.say(f"  ! {note}")
    path = save_run(run, lupin_home())
    term.say(f"Every sample saved to {path}.")
    ok = not run.stopped and c.gains_restored and c.torque_off
    return EXIT_OK if ok else EXIT_FAILED
