"""The simulated Feetech servo bus: a product feature, not only a test fake.

``servo.py`` one servo's control table, ``physics.py`` what its shaft does,
``bus.py`` the protocol over many servos (and the log tests assert on),
``faults.py`` injected line faults, ``pty_server.py`` all of it on a fake
serial port.
"""

from lupin_adapters.sim.bus import SimServoSpec, SimulatedBus, WriteRecord, build_sim_bus
from lupin_adapters.sim.pty_server import PtySimServer, serve
from lupin_adapters.sim.servo import SimServo

__all__ = [
    "PtySimServer",
    "SimServo",
    "SimServoSpec",
    "SimulatedBus",
    "WriteRecord",
    "build_sim_bus",
    "serve",
]
