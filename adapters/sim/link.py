"""The ``sim`` bus adapter: the profile's simulated servos on a pty, opened like a real bus.

``lupin run --sim`` uses this, so the daemon exercises the same codec, serial
transport and bus scheduler as on a robot; only the far end of the wire differs.
"""

from __future__ import annotations

from typing import Any

from lupin.config_models import RobotProfile
from lupin_adapters.serial_link import SerialLink
from lupin_adapters.sim.bus import SimServoSpec, build_sim_bus
from lupin_adapters.sim.pty_server import PtySimServer

# Holding torque against gravity, by joint name: the shoulder lift carries the
# most (the runbook's cooking shoulder), so droop and heating show there first.
GRAVITY = {"shoulder_lift": 120.0, "elbow_flex": 60.0, "elbow": 60.0, "wrist_flex": 20.0}


def sim_specs(profile: RobotProfile) -> list[SimServoSpec]:
    """One simulated servo per profile servo: arm joints in position mode, wheels in velocity."""
    specs = [
        SimServoSpec(
            id=j.id,
            mode=0,
            position=j.zero,
            gravity=GRAVITY.get(j.name, 0.0),
            min_limit=j.min,
            max_limit=j.max,
            p_gain=j.gains.p,
        )
        for j in profile.arm.joints
    ]
    if profile.base is not None:
        specs += [SimServoSpec(id=w.id, mode=1, position=2048) for w in profile.base.wheels]
    return specs


class SimLink(SerialLink):
    """A SerialLink that also owns (and closes) the simulator serving its pty."""

    server: PtySimServer

    async def close(self) -> None:
        await super().close()
        await self.server.close()


async def open_link(
    device: str, baud: int, *, profile: RobotProfile, wire_pacing: bool = False, **_: Any
) -> SimLink:
    """The ``sim`` entry of the ``lupin.bus`` group; ``device`` is ignored."""
    server = PtySimServer(build_sim_bus(sim_specs(profile)), baud=baud, wire_pacing=wire_pacing)
    path = await server.start()
    try:
        link = await SimLink.open(path, baud)
    except BaseException:
        await server.close()
        raise
    assert isinstance(link, SimLink)
    link.server = server
    return link
