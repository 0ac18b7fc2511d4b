"""``lupin gains sweep``: step one joint under each candidate gain set and record the response.

A gain is only defensible against a measurement (bring-up seed). Each trial
writes its gains with torque off, re-enables against the joint's present
position, steps the joint, and samples position and load at 50 Hz. Gains are
EEPROM registers, and a servo that latched them at torque-enable would run
every trial at the same gain and report a droop that mysteriously ignores Kp —
hence torque off for every write, so the joint goes briefly limp between trials.

Guards, because the sweep moves the arm and writes EEPROM: only the swept joint
is torqued; a step that would pass the soft limits (or the servo's own limit
registers) is refused, since trials that command different travel are not
comparable; the sweep stops at ``max_temp``; and in a ``finally`` — a crash or
Ctrl-C counts too — the joint is returned to where it started, the original
gains are written back and torque is dropped.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

from lupin.bench.gains import ServoGains, read_gains, write_gains
from lupin.bench.registers import EepromWriteFailed, ServoIO
from lupin.bench.step_response import Sample, TrialScore, score_trial, verdict
from lupin.config_models import JointConfig, RobotProfile
from lupin.joints import RAD_PER_COUNT

SWEEPS_DIR = "arm_gain_sweeps"
STATE = ("present_position", "present_load", "present_temperature", "moving")
MAX_MISSED = 5  # consecutive unanswered samples before the servo counts as lost
RETURN_TIMEOUT_S = 3.0


class SweepRefused(Exception):
    """The sweep will not start; nothing was written."""


class SweepStopped(Exception):
    """The sweep stopped partway (too hot, servo lost, a write not confirmed)."""


@dataclass(frozen=True)
class SweepSettings:
    joint: str
    trials: list[tuple[int, int]]  # (kp, ki) in order
    step_rad: float = -0.2
    max_temp: float = 55.0
    speed: int = 500  # goal_speed, counts/s: the seed's "double speed" was 1000
    rest_s: float = 0.5  # holding before each step, to measure where it starts
    hold_s: float = 1.5  # sampling after the step
    hz: float = 50.0


@dataclass
class SweepPlan:
    """What preflight found: the joint, where it rests and the gains to go back to."""

    joint: JointConfig
    original: ServoGains
    original_speed: int
    rest: int  # counts, where the joint started
    goal: int  # counts, where every trial steps to
    step_counts: int
    temperature: int
    others_torqued: list[str]


@dataclass
class Trial:
    kp: int
    ki: int
    kd: int
    samples: list[Sample] = field(default_factory=list)  # t < 0: before the step
    score: TrialScore | None = None


@dataclass
class Cleanup:
    returned_to: int | None = None  # counts, where the joint ended up
    gains_restored: bool = False
    torque_off: bool = False
    notes: list[str] = field(default_factory=list)


@dataclass
class SweepRun:
    plan: SweepPlan
    settings: SweepSettings
    started: str
    trials: list[Trial] = field(default_factory=list)
    stopped: str | None = None
    cleanup: Cleanup = field(default_factory=Cleanup)

    @property
    def scores(self) -> list[TrialScore]:
        return [t.score for t in self.trials if t.score is not None]

    def verdict(self) -> str:
        return verdict(self.scores)


async def preflight(io: ServoIO, profile: RobotProfile, settings: SweepSettings) -> SweepPlan:
    """Read what the sweep needs and refuse what it must not do. Writes nothing."""
    names = [j.name for j in profile.arm.joints]
    if settings.joint not in names:
        raise SweepRefused(f"no arm joint {settings.joint!r} (joints: {', '.join(names)})")
    joint = profile.joint(settings.joint)
    sid = joint.id
    regs = await io.read_many(sid, ("min_position_limit", "max_position_limit", "operating_mode"))
    state = await io.read_many(sid, ("present_position", "present_temperature"))
    speed = await io.read(sid, "goal_speed")
    original = await read_gains(io, sid)
    if regs is None or state is None or speed is None or original is None:
        raise SweepRefused(f"{joint.name} (id {sid}) does not answer")
    if regs["operating_mode"] != 0:
        raise SweepRefused(f"{joint.name} is in operating mode {regs['operating_mode']}, not 0")
    sign = -1 if joint.invert else 1
    step = round(sign * settings.step_rad / RAD_PER_COUNT)
    rest = state["present_position"]
    goal = rest + step
    if step == 0:
        raise SweepRefused(f"a step of {settings.step_rad} rad is under one count")
    if not joint.min <= goal <= joint.max:
        raise SweepRefused(
            f"a {settings.step_rad:+.3f} rad step from {rest} counts ends at {goal}, outside "
            f"{joint.name}'s soft limits {joint.min}..{joint.max}: it would clamp, and trials "
            f"that command different travel are not comparable"
        )
    lo, hi = regs["min_position_limit"], regs["max_position_limit"]
    if (lo or hi) and not lo <= goal <= hi:
        raise SweepRefused(
            f"the step ends at {goal} counts, outside the servo's own position limit "
            f"registers {lo}..{hi}: the servo would clamp it"
        )
    if state["present_temperature"] >= settings.max_temp:
        raise SweepRefused(
            f"{joint.name} is at {state['present_temperature']} °C, at or over "
            f"--max-temp {settings.max_temp:g} °C"
        )
    others = []
    for other in profile.arm.joints:
        if other.name != joint.name and await io.read(other.id, "torque_enable"):
            others.append(other.name)
    return SweepPlan(joint, original, speed, rest, goal, step, state["present_temperature"], others)


async def limp_joints(io: ServoIO, profile: RobotProfile, names: list[str]) -> None:
    """Drop torque on the named joints (only the swept joint may be torqued)."""
    for name in names:
        if not await io.set_torque(profile.joint(name).id, False):
            raise SweepRefused(f"{name}: no reply to torque off")


class _Runner:
    def __init__(
        self,
        io: ServoIO,
        plan: SweepPlan,
        settings: SweepSettings,
        on_trial: Callable[[int, Trial], None] | None,
    ) -> None:
        self.io = io
        self.plan = plan
        self.settings = settings
        self.sid = plan.joint.id
        self.on_trial = on_trial
        self.loop = asyncio.get_running_loop()

    async def must(self, ok: bool, what: str) -> None:
        if not ok:
            raise SweepStopped(f"{self.plan.joint.name}: no reply to {what}")

    async def goal(self, counts: int) -> None:
        await self.must(await self.io.write(self.sid, "goal_position", counts), "a goal write")

    async def sample(self, duration: float, t0: float) -> list[Sample]:
        """Sample at ``hz`` for ``duration``; t relative to ``t0``. Stops the sweep if too hot."""
        period = 1.0 / self.settings.hz
        out: list[Sample] = []
        due = self.loop.time()
        end = due + duration
        missed = 0
        while self.loop.time() < end:
            got = await self.io.read_many(self.sid, STATE)
            if got is None:
                missed += 1
                if missed >= MAX_MISSED:
                    raise SweepStopped(f"{self.plan.joint.name} stopped answering")
            else:
                missed = 0
                temp = got["present_temperature"]
                now = self.loop.time() - t0
                out.append(Sample(now, got["present_position"], got["present_load"], temp))
                if temp >= self.settings.max_temp:
                    raise SweepStopped(
                        f"{self.plan.joint.name} reached {temp} °C "
                        f"(--max-temp {self.settings.max_temp:g} °C)"
                    )
            due += period
            await asyncio.sleep(max(0.0, due - self.loop.time()))
        return out

    async def trial(self, index: int, trial: Trial) -> None:
        io, sid, s = self.io, self.sid, self.settings
        await self.must(await io.set_torque(sid, False), "torque off")
        try:
            await write_gains(io, sid, ServoGains(trial.kp, trial.kd, trial.ki))
        except EepromWriteFailed as exc:
            raise SweepStopped(str(exc)) from None
        # Re-enable against the present position: the goal is seeded first (bring-up seed).
        present = await io.read(sid, "present_position")
        if present is None:
            raise SweepStopped(f"{self.plan.joint.name} stopped answering")
        await self.goal(present)
        await self.must(await io.set_torque(sid, True), "torque on")
        t_rest = self.loop.time()
        before = await self.sample(s.rest_s, t_rest + s.rest_s)
        tail = before[-max(1, len(before) // 4) :]
        start = sum(x.position for x in tail) / len(tail) if tail else float(present)
        await self.goal(self.plan.goal)
        t_step = self.loop.time()
        trial.samples = [*before, *await self.sample(s.hold_s, t_step)]
        after = [x for x in trial.samples if x.t >= 0]
        trial.score = score_trial(
            after,
            start=start,
            goal=self.plan.goal,
            step_counts=self.plan.step_counts,
            kp=trial.kp,
            ki=trial.ki,
            kd=trial.kd,
        )
        if self.on_trial is not None:
            self.on_trial(index, trial)
        await self.goal(self.plan.rest)
        await self.settle()

    async def settle(self) -> int | None:
        """Wait (bounded) for the joint to stop; its position then.

        Stopped means the moving flag is clear and two readings a sample apart
        agree: the flag alone can still be clear from before the goal changed.
        """
        end = self.loop.time() + RETURN_TIMEOUT_S
        await asyncio.sleep(0.1)
        position = None
        while self.loop.time() < end:
            got = await self.io.read_many(self.sid, STATE)
            if got is not None:
                previous, position = position, got["present_position"]
                if not got["moving"] and previous is not None and abs(position - previous) <= 1:
                    break
            await asyncio.sleep(1.0 / self.settings.hz)
        return position

    async def cleanup(self, report: Cleanup) -> None:
        """Return, drop torque, restore the gains: each step tried whatever failed before."""
        io, sid, plan = self.io, self.sid, self.plan
        try:
            torque = await io.read(sid, "torque_enable")
            if torque:
                await self.goal(plan.rest)
                report.returned_to = await self.settle()
            else:
                report.returned_to = await io.read(sid, "present_position")
        except SweepStopped as exc:
            report.notes.append(f"could not return the joint: {exc}")
        report.torque_off = await io.set_torque(sid, False)
        try:
            if await read_gains(io, sid) != plan.original:  # spare the EEPROM a no-op write
                await write_gains(io, sid, plan.original)
            report.gains_restored = True
        except EepromWriteFailed as exc:
            report.notes.append(f"original gains {plan.original} not confirmed: {exc}")
        if not await io.write(sid, "goal_speed", plan.original_speed):
            report.notes.append("could not restore goal_speed")
        torque = await io.read(sid, "torque_enable")
        report.torque_off = torque == 0
        if not report.torque_off:
            report.notes.append("torque_enable does not read 0 after the sweep")


def new_run(plan: SweepPlan, settings: SweepSettings) -> SweepRun:
    """The record a sweep fills in; the caller keeps it, so it survives a Ctrl-C."""
    return SweepRun(plan, settings, datetime.now().astimezone().isoformat(timespec="seconds"))


async def run_sweep(
    io: ServoIO,
    run: SweepRun,
    *,
    on_trial: Callable[[int, Trial], None] | None = None,
) -> SweepRun:
    """Run every trial; the finally returns the joint, restores the gains, drops torque.

    A cancellation (Ctrl-C) is re-raised after the cleanup, with ``run.stopped``
    saying so; the caller still holds ``run`` to report and save.
    """
    plan, settings = run.plan, run.settings
    runner = _Runner(io, plan, settings, on_trial)
    try:
        if not await io.write(plan.joint.id, "goal_speed", settings.speed):
            raise SweepStopped(f"{plan.joint.name}: no reply to the goal_speed write")
        for index, (kp, ki) in enumerate(settings.trials):
            trial = Trial(kp, ki, plan.original.d)
            run.trials.append(trial)
            await runner.trial(index, trial)
    except SweepStopped as exc:
        run.stopped = str(exc)
    except asyncio.CancelledError:
        run.stopped = "interrupted"
        raise
    finally:
        await runner.cleanup(run.cleanup)
    return run


def run_record(run: SweepRun) -> dict[str, Any]:
    """Every sample and score, as JSON-ready data."""
    plan = run.plan
    return {
        "joint": plan.joint.name,
        "id": plan.joint.id,
        "started": run.started,
        "settings": asdict(run.settings),
        "original_gains": asdict(plan.original),
        "rest_counts": plan.rest,
        "goal_counts": plan.goal,
        "step_counts": plan.step_counts,
        "trials": [
            {
                "kp": t.kp,
                "ki": t.ki,
                "kd": t.kd,
                "samples_columns": ["t", "position", "load", "temperature"],
                "samples": [[round(s.t, 4), s.position, s.load, s.temperature] for s in t.samples],
                "score": asdict(t.score) if t.score is not None else None,
            }
            for t in run.trials
        ],
        "verdict": run.verdict(),
        "stopped": run.stopped,
        "cleanup": asdict(run.cleanup),
    }


def save_run(run: SweepRun, home: Path) -> Path:
    """Write the run to ``$LUPIN_HOME/arm_gain_sweeps/<stamp>.json`` and return the path."""
    directory = home / SWEEPS_DIR
    directory.mkdir(parents=True, exist_ok=True)
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    path = directory / f"{stamp}.json"
    n = 1
    while path.exists():
        n += 1
        path = directory / f"{stamp}-{n}.json"
    path.write_text(json.dumps(run_record(run), indent=1) + "\n", encoding="utf-8")
    return path
