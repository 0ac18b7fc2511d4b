"""``lupin check``'s core: who answers, how each servo is, and where each joint sits.

Read-only. The profile's ids are pinged first, then a short scan finds strays
(a servo with a wrong id would otherwise be invisible until it collides); a
scan of all 254 ids costs a reply timeout per silent id, so it is a range,
0..20 unless told.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lupin import control_table as ct
from lupin.bench.registers import ServoIO
from lupin.config_models import RobotProfile
from lupin.joints import arm_geometry
from lupin.protocol import ServoError

DEFAULT_SCAN = range(0, 21)

# Three short reads instead of one long one: the EEPROM block, torque, the live state.
IDENTITY = (
    "firmware_major",
    "firmware_minor",
    "model",
    "min_position_limit",
    "max_position_limit",
    "p_coefficient",
    "d_coefficient",
    "i_coefficient",
    "homing_offset",
    "operating_mode",
)
STATE = (
    "present_position",
    "present_load",
    "present_voltage",
    "present_temperature",
    "status",
)


@dataclass
class ServoHealth:
    """One profile servo as ``check`` found it; ``registers`` is empty if it did not answer."""

    name: str
    id: int
    kind: str  # "arm" or "wheel"
    expected_mode: int
    answered: bool = False
    registers: dict[str, int] = field(default_factory=dict)
    torque: int | None = None
    position_rad: float | None = None  # arm joints: present position about the zero
    problems: list[str] = field(default_factory=list)

    @property
    def firmware(self) -> str | None:
        r = self.registers
        if "firmware_major" not in r:
            return None
        return f"{r['firmware_major']}.{r['firmware_minor']}"


@dataclass
class CheckReport:
    servos: list[ServoHealth]
    strays: list[int]
    scanned: range

    @property
    def missing(self) -> list[ServoHealth]:
        return [s for s in self.servos if not s.answered]

    @property
    def ok(self) -> bool:
        """Every profile servo answered (the exit status of ``check``)."""
        return not self.missing


def profile_servos(profile: RobotProfile) -> list[ServoHealth]:
    out = [ServoHealth(j.name, j.id, "arm", ct.OperatingMode.POSITION) for j in profile.arm.joints]
    if profile.base is not None:
        out += [
            ServoHealth(w.name, w.id, "wheel", ct.OperatingMode.VELOCITY)
            for w in profile.base.wheels
        ]
    return out


async def run_check(io: ServoIO, profile: RobotProfile, scan: range = DEFAULT_SCAN) -> CheckReport:
    """Enumerate, read health and the zero snapshot. Writes nothing."""
    servos = profile_servos(profile)
    geometry = arm_geometry(profile.arm)
    for servo in servos:
        servo.answered = await io.ping(servo.id)
        if servo.answered:
            await _read_health(io, servo)
            g = geometry.get(servo.name) if servo.kind == "arm" else None
            pos = servo.registers.get("present_position")
            if g is not None and pos is not None:
                servo.position_rad = g.counts_to_rad(pos)
    known = {s.id for s in servos}
    strays = [sid for sid in scan if sid not in known and await io.ping(sid)]
    return CheckReport(servos, strays, scan)


async def _read_health(io: ServoIO, servo: ServoHealth) -> None:
    for names in (IDENTITY, STATE):
        got = await io.read_many(servo.id, names)
        if got is None:
            servo.problems.append(f"no reply reading {names[0]}..{names[-1]}")
        else:
            servo.registers.update(got)
    servo.torque = await io.read(servo.id, "torque_enable")
    if servo.torque is None:
        servo.problems.append("no reply reading torque_enable")
    mode = servo.registers.get("operating_mode")
    if mode is not None and mode != servo.expected_mode:
        # In wheel mode a position goal is obeyed as a speed (bring-up seed).
        want = ct.OperatingMode(servo.expected_mode).name.lower()
        servo.problems.append(f"operating mode {mode}, expected {servo.expected_mode} ({want})")
    status = servo.registers.get("status")
    if status:
        servo.problems.append(f"status error bits {ServoError(status)!r}")
