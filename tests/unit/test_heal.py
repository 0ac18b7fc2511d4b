"""Heal's tri-state, with a fake daemon; and the suspend/resume detector."""

from __future__ import annotations

import time

import pytest

from lupin.heal import ResumeWatcher, auto_home, heal
from lupin.protocol import ServoError


class FakeTarget:
    def __init__(self, found: dict[int, tuple[int, int, int]] | None, reenable_ok: bool = True):
        self.found = found
        self.reenable_ok = reenable_ok
        self.reenabled: list[int] = []
        self.crashed: list[str] = []

    async def enumerate(self) -> dict[int, tuple[int, int, int]] | None:
        return self.found

    def expected(self) -> dict[int, tuple[str, int, bool]]:
        return {1: ("shoulder_pan", 0, True), 2: ("shoulder_lift", 0, True), 7: ("left", 1, False)}

    async def reenable(self, servo_id: int) -> bool:
        self.reenabled.append(servo_id)
        return self.reenable_ok

    def dead_tasks(self) -> list[str]:
        return self.crashed

    async def restart_tasks(self) -> list[str]:
        done, self.crashed = self.crashed, []
        return done


async def test_unknown_when_nothing_answers_and_nothing_is_attempted() -> None:
    for found in (None, {}):
        target = FakeTarget(found)
        report = await heal(target)
        assert report.result == "unknown"
        assert target.reenabled == []


async def test_healthy() -> None:
    report = await heal(FakeTarget({1: (0, 1, 0), 2: (0, 1, 0), 7: (1, 0, 0)}))
    assert report.result == "healthy"


async def test_unloaded_servo_is_reenabled_and_named() -> None:
    target = FakeTarget({1: (0, 1, 0), 2: (0, 0, int(ServoError.OVERLOAD)), 7: (1, 0, 0)})
    report = await heal(target)
    assert report.result == "healed" and target.reenabled == [2]
    assert any("shoulder_lift" in d and "overload" in d for d in report.details)


async def test_latched_servo_that_will_not_reenable_fails() -> None:
    target = FakeTarget({1: (0, 1, 0), 2: (0, 0, 32), 7: (1, 0, 0)}, reenable_ok=False)
    assert (await heal(target)).result == "failed"


async def test_wrong_mode_is_never_rewritten_and_fails() -> None:
    target = FakeTarget({1: (0, 1, 0), 2: (0, 1, 0), 7: (0, 0, 0)})
    report = await heal(target)
    assert report.result == "failed" and target.reenabled == []
    assert any("left (id 7) is in mode 0, expected 1" in d for d in report.details)


async def test_crashed_task_restart_counts_as_healed() -> None:
    target = FakeTarget({1: (0, 1, 0), 2: (0, 1, 0), 7: (1, 0, 0)})
    target.crashed = ["control-loop"]
    report = await heal(target)
    assert report.result == "healed"
    assert "restarted the crashed control-loop task" in report.details


async def test_auto_home_gives_up_without_joint_state() -> None:
    parked: list[bool] = []

    async def never(_timeout: float) -> bool:
        return False

    async def park() -> None:
        parked.append(True)

    assert await auto_home(never, park, wait_s=0.01, settle_s=0) == "failed"
    assert parked == []


def test_resume_is_detected_from_boot_time_jumping_ahead(monkeypatch: pytest.MonkeyPatch) -> None:
    boot = [1000.0]
    mono = [10.0]
    monkeypatch.setattr(time, "clock_gettime", lambda _clock: boot[0])
    monkeypatch.setattr(time, "monotonic", lambda: mono[0])
    watcher = ResumeWatcher(jump=2.0)
    boot[0] += 1.0
    mono[0] += 1.0
    assert not watcher.resumed()  # both clocks advanced together: awake
    boot[0] += 600.0  # suspended for ten minutes: monotonic stood still
    mono[0] += 1.0
    assert watcher.resumed()
    boot[0] += 1.0
    mono[0] += 1.0
    assert not watcher.resumed()
