"""The simulated servos and the real daemon (with its API and pad task) in one event loop.

One process, one clock: the simulator (:class:`PtySimServer` on a pty, replies
paced at 1 Mbaud) stamps every packet it receives with ``time.monotonic()``,
and the benchmark stamps its stimuli with the same clock, so a latency is a
plain difference. The daemon is the real :class:`lupin.daemon.Daemon` over the
real serial path (pyserial-asyncio on the pty), with :class:`ApiServer` on a
free loopback port, and its pad task (:func:`lupin.pad_task.run_pad`, wired as
``Daemon.prepare_pad`` wires it) reading a :class:`PadFeed`.
"""

from __future__ import annotations

import contextlib
import tempfile
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path

from benchlib.pad_feed import PadFeed
from lupin import control_table as ct
from lupin.api import ApiServer
from lupin.config import load_profile
from lupin.config_models import RobotProfile
from lupin.daemon import Daemon, DaemonOptions
from lupin.pad_mapping import load_mapping
from lupin.pad_task import PadStatus, run_pad
from lupin.protocol import Instruction
from lupin.teleop import ArmTeleop, BaseTeleop
from lupin_adapters.sim import PtySimServer, SimulatedBus, build_sim_bus
from lupin_adapters.sim.link import sim_specs

GOAL_SPEED = ct.REGISTERS["goal_speed"].address
LAYOUT = "xbox-bluetooth"


@dataclass
class Rig:
    profile: RobotProfile
    sim: SimulatedBus
    daemon: Daemon
    url: str
    pad: PadFeed

    @property
    def wheel_ids(self) -> list[int]:
        return [w.id for w in self.profile.base.wheels] if self.profile.base else []

    @property
    def tick_period(self) -> float:
        return 1.0 / self.profile.control.tick_hz

    def wheel_goals(self, since: float) -> list[tuple[float, int, int]]:
        """(time received, servo id, goal speed) of every wheel goal-speed write since ``since``."""
        out = []
        for w in self.sim.writes_to(GOAL_SPEED, since=since):
            value = w.value("goal_speed")
            if w.id in self.wheel_ids and value is not None:
                out.append((w.t, w.id, value))
        return out

    def sync_reads(self, after: float, before: float) -> int:
        """SYNC_READs (tick starts, as the servos see them) received in (after, before)."""
        return sum(
            1 for t, _ in self.sim.instructions(Instruction.SYNC_READ, since=after) if t < before
        )


@contextlib.asynccontextmanager
async def rig(*, wire_pacing: bool = True) -> AsyncIterator[Rig]:
    """Start the simulator, the daemon (limp arm, no auto-home), its API and its pad task."""
    with tempfile.TemporaryDirectory(prefix="lupin-bench-") as tmp:
        home = Path(tmp)
        profile = load_profile("so101", home=home, overrides={"api": {"port": 0}})
        sim = build_sim_bus(sim_specs(profile))
        server = PtySimServer(sim, baud=profile.bus.baud, wire_pacing=wire_pacing)
        path = await server.start()
        daemon = Daemon(profile, DaemonOptions(bus_port=path, auto_home=False, pad="none"))
        api: ApiServer | None = None
        try:
            await daemon.start()
            if not await daemon.wait_ready(5.0):
                raise RuntimeError("the daemon read no full state from the simulator in 5 s")
            api = ApiServer(daemon.services, profile.api, env={})
            url = await api.start()
            pad = PadFeed()
            _start_pad(daemon, pad, home)
            pad.put()  # the pad at rest: a dead-man held from the start would not count
            yield Rig(profile, sim, daemon, url, pad)
        finally:
            if api is not None:
                await api.stop()
            await daemon.stop()
            await server.close()


def _start_pad(daemon: Daemon, feed: PadFeed, home: Path) -> None:
    """The pad task as ``Daemon.prepare_pad`` builds it, reading ``feed`` instead of a device."""
    mapping = load_mapping(LAYOUT, home=home)
    daemon.pad_info = {"layout": LAYOUT, "mapping": mapping.model_dump()}
    daemon.pad_status = PadStatus(layout=LAYOUT)
    windows = {n: g.window_rad for n, g in daemon.geometry.items()}
    arm_teleop = ArmTeleop(mapping, daemon.arm.names, windows, gripper=daemon.profile.arm.gripper)
    status = daemon.pad_status

    async def run() -> None:
        await run_pad(
            lambda: feed,
            BaseTeleop(mapping),
            arm_teleop,
            submit_twist=daemon.submit_twist,
            arm=daemon.arm,
            clock=daemon.clock,
            status=status,
        )

    daemon.start_pad(run)
