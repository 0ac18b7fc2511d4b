"""Test kit for the bench tools: the simulator in the test's loop, the tool on a pseudo-terminal.

The simulator runs in the test's event loop (so a test can move limp joints by
hand, inject faults and read every packet); the tool runs as ``python -m
lupin ...`` with stdin, stdout and stderr on a pty the test opened, exactly as
at a terminal: prompts, the live table, Enter and Ctrl-C all go through it.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
from collections.abc import Awaitable, Callable, Mapping, Sequence
from pathlib import Path

from lupin.config import load_profile
from lupin.config_models import RobotProfile
from lupin.joints import arm_geometry
from lupin_adapters.sim import PtySimServer, SimulatedBus, build_sim_bus
from lupin_adapters.sim.link import sim_specs
from lupintest.pty_tool import PtyTool as Tool

MakeSim = Callable[..., Awaitable["Sim"]]
StartTool = Callable[..., Tool]


@dataclasses.dataclass
class Sim:
    bus: SimulatedBus
    server: PtySimServer
    path: str
    profile: RobotProfile


async def start_sim(
    positions: Mapping[int, float] | None = None,
    *,
    extra_ids: Sequence[int] = (),
    p_gain: Mapping[int, int] | None = None,
) -> Sim:
    """The so101 profile's servos on a pty, starting at ``positions`` (counts) if given."""
    profile = load_profile("so101")
    specs = []
    for spec in sim_specs(profile):
        if positions and spec.id in positions:
            spec = dataclasses.replace(spec, position=positions[spec.id])
        if p_gain and spec.id in p_gain:
            spec = dataclasses.replace(spec, p_gain=p_gain[spec.id])
        specs.append(spec)
    specs += [dataclasses.replace(specs[0], id=i) for i in extra_ids]
    bus = build_sim_bus(specs)
    server = PtySimServer(bus, baud=profile.bus.baud)
    path = await server.start()
    return Sim(bus, server, path, profile)


def ramp(*points: float, step: float = 150.0) -> list[float]:
    """Positions from point to point in steps no bigger than ``step`` (a hand, not a jump)."""
    out = [points[0]]
    for target in points[1:]:
        while abs(target - out[-1]) > step:
            out.append(out[-1] + (step if target > out[-1] else -step))
        out += [target] * 3  # dwell at each stop, so the 20 Hz sampler sees it
    return out


def backups(home: Path) -> list[str]:
    """The offset backups in ``home``: the current one and any kept beside it."""
    return sorted(p.name for p in home.glob("arm_offsets_backup*.yaml"))


async def sweep_by_hand(
    bus: SimulatedBus, paths: Mapping[int, Sequence[float]], dwell: float = 0.05
) -> None:
    """Move the limp servos along ``paths`` (present counts, unwrapped) together."""
    for k in range(max(len(p) for p in paths.values())):
        for sid, path in paths.items():
            bus.servo(sid).move_by_hand(path[min(k, len(path) - 1)] % 4096)
        await asyncio.sleep(dwell)


def lerobot_degrees(present: int, motor: Mapping[str, int]) -> float:
    """What LeRobot reads for ``present`` in its DEGREES mode, written from its documented rule.

    ``lerobot/motors`` clamps the present position into the calibrated range and
    measures it from the range's middle: ``(present - mid) * 360 / 4095``.
    """
    lo, hi = motor["range_min"], motor["range_max"]
    return (min(max(present, lo), hi) - (lo + hi) / 2) * 360 / 4095


def lupin_degrees(home: Path, joint: str, present: int) -> float:
    """What the daemon reads for ``present`` with this home's calibration."""
    arm = load_profile("so101", home=home).arm
    return math.degrees(arm_geometry(arm)[joint].counts_to_rad(present))
