"""One simulated STS3215-class servo: its control table memory and the rules for writing it.

The memory is the real 256-byte table, so any read the vendor SDK or the daemon
makes is answered from the same bytes a real servo would hold. Writes follow the
servo's rules: read-only registers ignore writes, EEPROM (addresses below 40)
only changes while lock (55) is 0, and ``torque_enable = 128`` recentres.
The physics (motion, droop, sag, heat, trips) lives in ``physics.py``.
"""

from __future__ import annotations

from lupin import control_table as ct
from lupin.protocol import ServoError
from lupin_adapters.sim.physics import ADDR_OVERLOAD_TORQUE, ADDR_PROTECTION_TIME, Physics

REG = ct.REGISTERS
TABLE_SIZE = 256

_READONLY = frozenset(
    a for r in REG.values() if r.readonly for a in range(r.address, r.address + r.size)
)

# Power-up values of an STS3215 as shipped (firmware 3.x, model 777).
_DEFAULTS: dict[str, int] = {
    "firmware_major": 3,
    "firmware_minor": 10,
    "model": 777,
    "baud_rate": 0,  # 1 Mbaud
    "return_delay": 0,
    "status_return_level": 1,  # answer every instruction
    "max_temperature_limit": 70,
    "max_voltage_limit": 80,
    "min_voltage_limit": 40,
    "max_torque_limit": 1000,
    "p_coefficient": 32,
    "d_coefficient": 32,
    "i_coefficient": 0,
    "torque_limit": 1000,
    # Locked at power-up, so a tool that forgets to unlock (LeRobot's tooling
    # writes Lock = 0 before EEPROM writes) fails here, not on the robot.
    "lock": 1,
    "present_voltage": 51,  # 5.1 V, what the bring-up seed measured on the SO-101
}


class SimServo:
    """One servo on the simulated bus. Positions are in counts (0..4095).

    ``position`` is where the shaft starts (the homing offset starts at 0, so
    it is also the first present position and the power-up goal). ``gravity``
    is the holding load, per mille of full effort, pulling toward lower counts
    (negative: higher); it sets the droop and heats a holding servo.
    ``sag_rate`` (counts/s) lets a limp joint fall toward ``rest`` (default:
    the position limit gravity pulls toward). ``trip`` is what a thermal or
    overload trip does: ``"unload"`` drops torque, ``"latch"`` ignores every
    write from then on (the runbook's older failure) until ``power_cycle()``.
    """

    def __init__(
        self,
        id: int,
        *,
        mode: int = ct.OperatingMode.POSITION,
        position: float = 2048.0,
        gravity: float = 0.0,
        sag_rate: float = 0.0,
        rest: float | None = None,
        min_limit: int = 0,
        max_limit: int = 4095,
        p_gain: int = 32,
        temperature: float = 27.0,
        trip: str = "unload",
    ) -> None:
        if trip not in ("unload", "latch"):
            raise ValueError(f"trip must be 'unload' or 'latch', got {trip!r}")
        self.memory = bytearray(TABLE_SIZE)
        self.memory[ADDR_PROTECTION_TIME] = 200  # 2 s
        self.memory[ADDR_OVERLOAD_TORQUE] = 80
        for name, value in _DEFAULTS.items():
            self.set(name, value)
        self.set("id", id)
        self.set("operating_mode", mode)
        self.set("min_position_limit", min_limit)
        self.set("max_position_limit", max_limit)
        self.set("p_coefficient", p_gain)
        self.actual = float(position) % 4096  # the physical shaft angle (homing offset 0 now)
        self.set("goal_position", round(self.actual) % 4096)  # power-up goal = where it is
        self.latched = False
        self.trip = trip
        self._forced = ServoError(0)
        self._faults = ServoError(0)
        self._pending: tuple[int, bytes] | None = None  # a REG_WRITE awaiting ACTION
        self.physics = Physics(
            self, gravity=gravity, sag_rate=sag_rate, rest=rest, temperature=temperature
        )

    # -- register access --------------------------------------------------------

    def get(self, name: str) -> int:
        reg = REG[name]
        return ct.decode_value(reg, self.memory[reg.address : reg.address + reg.size])

    def set(self, name: str, value: int) -> None:
        """Poke a register directly, bypassing the write rules (the servo's own updates, tests)."""
        reg = REG[name]
        self.memory[reg.address : reg.address + reg.size] = ct.encode_value(reg, value)

    @property
    def id(self) -> int:
        return self.memory[REG["id"].address]

    @property
    def torque(self) -> bool:
        return self.memory[REG["torque_enable"].address] == 1

    @property
    def error(self) -> ServoError:
        """The error byte of this servo's status packets."""
        return self._forced | self._faults | self.physics.live_errors()

    def read(self, address: int, length: int) -> bytes:
        """Bytes from the table, present values refreshed first; past the end reads as 0."""
        self.physics.publish()
        self.set("status", int(self.error))
        chunk = bytes(self.memory[address : address + length])
        return chunk + bytes(length - len(chunk))

    def write(self, address: int, data: bytes) -> None:
        """A WRITE as the servo applies it: byte by byte, under the lock and read-only rules."""
        if self.latched:
            return  # the runbook's latch: commands ignored, readback still works
        unlocked = self.memory[REG["lock"].address] == 0
        torque_addr = REG["torque_enable"].address
        old_offset = self.get("homing_offset")
        for i, byte in enumerate(data):
            addr = address + i
            if addr >= TABLE_SIZE or addr in _READONLY:
                continue
            if addr < ct.EEPROM_END and not unlocked:
                continue
            if addr == torque_addr:
                self._write_torque(byte)
                continue
            self.memory[addr] = byte
        if self.get("homing_offset") != old_offset:
            self.physics.frame_changed()

    def reg_write(self, address: int, data: bytes) -> None:
        if not self.latched:
            self._pending = (address, bytes(data))

    def action(self) -> None:
        if self._pending is not None and not self.latched:
            address, data = self._pending
            self._pending = None
            self.write(address, data)

    def _write_torque(self, value: int) -> None:
        mem = REG["torque_enable"].address
        if value == ct.TorqueEnable.RECENTRE:
            # The servo's own calibration: this position reads 2048 from now on.
            # It rewrites EEPROM itself, so the lock does not apply; torque stays off.
            offset = round(self.actual) - 2048
            self.set("homing_offset", max(-2047, min(2047, offset)))
            self.memory[mem] = 0
            self.physics.frame_changed()
        elif value:
            was_on = self.memory[mem] == 1
            self.memory[mem] = 1
            # An operator re-enabling an unloaded servo is how it re-loads (runbook);
            # the trip's cause stays readable until then. Still too hot: trips again.
            self._faults = ServoError(0)
            if not was_on:
                self.physics.torque_on()
        else:
            self.memory[mem] = 0

    # -- hooks used by the physics ----------------------------------------------

    def unload(self, why: ServoError) -> None:
        """The protective trip: drop torque (or latch, the older failure) and flag why."""
        self._faults |= why
        if self.trip == "latch":
            self.latched = True
        else:
            self.memory[REG["torque_enable"].address] = 0

    # -- test helpers -----------------------------------------------------------

    def step(self, dt: float) -> None:
        self.physics.step(dt)

    def move_by_hand(self, present: float) -> None:
        """Put the shaft where a hand would, given in the present (offset) frame."""
        self.actual = (present + self.get("homing_offset")) % 4096
        self.physics.frame_changed()

    def force_error(self, bits: int) -> None:
        """Make every status packet carry these error bits (0 clears)."""
        self._forced = ServoError(bits)

    def latch(self) -> None:
        """Enter the latched fault: writes ignored, reads answered, until power_cycle()."""
        self.latched = True

    def power_cycle(self) -> None:
        """What a hard power-cycle clears: the latch, the faults and the RAM registers."""
        self.latched = False
        self._faults = ServoError(0)
        self._pending = None
        for name in ("torque_enable", "acceleration", "goal_time", "goal_speed"):
            self.set(name, 0)
        self.set("torque_limit", 1000)
        self.set("lock", 1)
        self.set("goal_position", self.physics.present_counts())
        self.physics.reset_motion()

    @property
    def present_position(self) -> int:
        return self.physics.present_counts()

    def __repr__(self) -> str:
        return f"SimServo(id={self.id}, present={self.present_position}, torque={self.torque})"
