"""The pad task on real (short) time: autorepeat, release, vanish, reader faults, arm steps."""

from __future__ import annotations

import asyncio
import dataclasses
import itertools
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from lupin.arm import ArmCommander, Torque
from lupin.config import load_profile
from lupin.joints import arm_geometry
from lupin.mux import ZERO_TWIST, Twist
from lupin.pad import PadFrame, PadReader
from lupin.pad_mapping import load_mapping
from lupin.pad_task import PadStatus, run_pad
from lupin.teleop import ArmTeleop, BaseTeleop

LB, B = 6, 1


def bt(*, lb: bool = False, fwd: float = 0.0, buttons: tuple[int, ...] = ()) -> PadFrame:
    pressed = set(buttons) | ({LB} if lb else set())
    axes = (0.0, fwd, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0)
    return PadFrame(0.0, axes, tuple(int(i in pressed) for i in range(15)))


class Scripted:
    """A reader that plays (delay, item) pairs, then stays quiet, ends, or raises."""

    transport = "test"

    def __init__(self, script: list[tuple[float, PadFrame | None]], end: str = "quiet") -> None:
        self.name = "scripted"
        self.script, self.end, self.closed = script, end, False

    async def frames(self) -> AsyncIterator[PadFrame | None]:
        for delay, item in self.script:
            await asyncio.sleep(delay)
            yield item
        if self.end == "raise":
            raise OSError("the pad went away badly")
        if self.end == "quiet":
            await asyncio.Event().wait()

    async def close(self) -> None:
        self.closed = True


class Recorder:
    def __init__(self) -> None:
        self.start = time.monotonic()
        self.sent: list[tuple[float, str, Twist]] = []

    def __call__(self, source: str, twist: Twist) -> None:
        self.sent.append((time.monotonic() - self.start, source, twist))


def base() -> BaseTeleop:
    return BaseTeleop(load_mapping("xbox-bluetooth"))


async def run(
    readers: list[Scripted], rec: Recorder, seconds: float, **kwargs: Any
) -> tuple[PadStatus, list[Scripted]]:
    status = PadStatus(layout="xbox-bluetooth")
    opened: list[Scripted] = []

    def open_reader() -> PadReader:
        reader = readers[len(opened)]
        opened.append(reader)
        return reader

    kwargs.setdefault("arm_teleop", None)
    kwargs.setdefault("arm", None)
    task = asyncio.create_task(
        run_pad(
            open_reader,
            kwargs.pop("base_teleop", base()),
            kwargs.pop("arm_teleop"),
            submit_twist=rec,
            arm=kwargs.pop("arm"),
            clock=time.monotonic,
            status=status,
            backoff=(0.05, 0.2),
            **kwargs,
        )
    )
    done, _ = await asyncio.wait({task}, timeout=seconds)
    before_cancel = dataclasses.replace(status)
    if not done:
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        # Cancelled (the daemon stopping) counts as a release too.
        assert not status.connected and not status.driving
    return before_cancel, opened


async def test_steady_hold_autorepeats_at_20hz_then_one_zero_and_silence() -> None:
    rec = Recorder()
    script = [(0.0, bt()), (0.05, bt(lb=True)), (0.01, bt(lb=True, fwd=1.0)), (0.6, bt())]
    await run([Scripted(script)], rec, 1.1)
    drive = [t for t, _, tw in rec.sent if tw.linear_x == pytest.approx(0.2)]
    assert len(drive) >= 10  # 0.6 s of steady hold with no new frames
    gaps = [b - a for a, b in itertools.pairwise(drive)]
    assert max(gaps) < 0.1  # far inside the 0.3 s joy timeout: never drops out
    after = [(t, tw) for t, _, tw in rec.sent if t > drive[-1]]
    assert [tw for _, tw in after] == [ZERO_TWIST]  # exactly one zero, then silence
    assert all(src == "joy" for _, src, _ in rec.sent)


async def test_vanish_mid_drive_is_one_zero_and_reconnect_does_not_resume() -> None:
    rec = Recorder()
    script = [
        (0.0, bt()),
        (0.02, bt(lb=True)),
        (0.02, bt(lb=True, fwd=1.0)),
        (0.1, None),
        (0.1, bt(lb=True, fwd=1.0)),  # back, still held: must not move
    ]
    status, _ = await run([Scripted(script)], rec, 0.6)
    zeros_after_drive = [tw for t, _, tw in rec.sent if t > 0.12]
    assert zeros_after_drive == [ZERO_TWIST]
    assert status.connected and not status.driving and status.deadman_held


async def test_reader_fault_counts_as_vanish_and_is_reopened_with_backoff() -> None:
    rec = Recorder()
    first = Scripted([(0.0, bt()), (0.02, bt(lb=True)), (0.02, bt(lb=True, fwd=1.0))], "raise")
    second = Scripted([(0.3, bt())])
    status, opened = await run([first, second], rec, 0.6)
    assert opened == [first, second] and first.closed
    assert status.reader_errors == 1 and status.connected
    assert [tw for _, _, tw in rec.sent].count(ZERO_TWIST) == 2  # the press, then the fault
    (drive_t, _, drive), (zero_t, _, zero) = rec.sent[-2:]
    assert drive.linear_x == pytest.approx(0.2) and zero == ZERO_TWIST
    assert zero_t - drive_t < 0.03  # at the fault, not when the reader comes back


async def test_finished_replay_returns_after_a_release() -> None:
    rec = Recorder()
    script = [(0.0, bt()), (0.02, bt(lb=True)), (0.02, bt(lb=True, fwd=1.0))]
    status, _ = await run([Scripted(script, end="stop")], rec, 1.0)
    assert rec.sent[-1][2] == ZERO_TWIST and not status.connected


async def test_on_state_reports_edges() -> None:
    rec = Recorder()
    states: list[dict[str, Any]] = []
    script = [(0.0, bt()), (0.02, bt(lb=True)), (0.02, bt(lb=True)), (0.02, bt())]
    await run([Scripted(script)], rec, 0.2, on_state=states.append)
    edges = [(s["connected"], s["deadman_held"], s["driving"]) for s in states]
    assert edges == [
        (True, False, False),
        (True, True, True),
        (True, False, False),
        (False, False, False),  # the task was cancelled
    ]
    assert states[0]["layout"] == "xbox-bluetooth" and states[0]["source"] == "joy"
    assert states[-1]["last_frame_age"] is not None


async def test_arm_steps_at_10hz_through_the_commander(tmp_path: Path) -> None:
    profile = load_profile("so101", home=tmp_path)
    geo = arm_geometry(profile.arm)
    arm = ArmCommander(geo)
    arm.observe(dict.fromkeys(geo, 0.0), time.monotonic())
    for n in arm.names:
        arm.set_torque_state(n, Torque.ON)
    arm.gate_open = True
    teleop = ArmTeleop(
        load_mapping("xbox-bluetooth"),
        list(geo),
        {n: g.window_rad for n, g in geo.items()},
        gripper=profile.arm.gripper,
    )
    rec = Recorder()
    script = [(0.0, bt()), (0.02, bt(buttons=(B,))), (0.33, bt())]
    await run([Scripted(script)], rec, 0.6, arm_teleop=teleop, arm=arm)
    assert arm.commanded is not None
    # Held 0.33 s: steps at press, +0.1, +0.2, +0.3 -> 4 steps of 0.15.
    assert arm.commanded["shoulder_pan"] == pytest.approx(0.6)
    assert rec.sent == []  # LB never held: the base stayed silent


def test_status_as_dict_has_an_age() -> None:
    status = PadStatus(layout="ds4", last_frame_at=10.0)
    assert status.as_dict(10.5)["last_frame_age"] == pytest.approx(0.5)
    assert PadStatus().as_dict(1.0)["last_frame_age"] is None
