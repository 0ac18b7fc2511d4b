"""What a simulated servo's shaft does between packets: motion, droop, sag, heat and trips.

Deliberately simple, but every behaviour the seeds measured or suffered is here:

- position mode follows a speed- and acceleration-limited profile to the goal,
  and settles short of it by a proportional droop, ``gravity * DROOP_K / P``
  (the bring-up seed's Kp sweep: P x error stays constant, so doubling P halves
  the error; I = 0 never integrates it away);
- torque off is limp: the goal is not held, and a joint given a ``sag_rate``
  falls toward its rest position;
- velocity mode spins at ``goal_speed``;
- holding a heavy load heats the servo, and over the temperature limit, or in
  an overload that persists, it trips (the runbook's cooking shoulder_lift).

Gravity is a constant holding load (per mille of full effort, the unit of
``present_load``) that pulls toward lower present counts; negative pulls the
other way. It does not vary with pose: a simplification, kept so the droop law
can be checked at any pose.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from lupin import control_table as ct
from lupin.protocol import ServoError

if TYPE_CHECKING:
    from lupin_adapters.sim.servo import SimServo

MAX_SPEED = 3000.0  # counts/s: what goal_speed 0 means, and the fastest the shaft turns
ACCEL_UNIT = 8.7 * 4096 / 360  # counts/s² per unit of register 41 (8.7 °/s², ≈ 99)
# Droop constant: counts of steady error x P per unit of gravity load. With the
# SO-101 shoulder's gravity (120) at the shipped P = 16 the error is 44 counts
# = 0.068 rad, the seed's measured droop at Kp 16; P x error stays 16 x 44.
DROOP_K = 5.9
SO101_SHOULDER_GRAVITY = 120.0
DROOP_TAU = 0.05  # s: how fast the droop builds after a change (the loop's stiffness)
SUBSTEP = 0.005  # s: long steps are cut into these, so a test may step minutes at once
HEAT_THRESHOLD = 300.0  # load (per mille) above which holding heats the motor
HEAT_RATE = 0.002  # °C/s per unit of load above the threshold
COOL_TAU = 120.0  # s: cooling time constant toward ambient
AMPS_PER_LOAD = 0.3  # present_current units (6.5 mA) per unit of load
SPIN_LOAD = 1 / 30  # wheel friction: load per count/s in velocity mode
# Not named by the codec (the daemon never touches them) but the overload trip
# reads them, so they sit in the servo's memory at their real addresses.
ADDR_PROTECTION_TIME = 35  # 10 ms units: how long an overload may persist
ADDR_OVERLOAD_TORQUE = 36  # % of full effort that counts as an overload


def _clamp(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


class Physics:
    """The shaft of one SimServo, stepped by ``step(dt)``."""

    def __init__(
        self,
        servo: SimServo,
        *,
        gravity: float,
        sag_rate: float,
        rest: float | None,
        temperature: float,
    ) -> None:
        self.servo = servo
        self.gravity = gravity
        self.sag_rate = sag_rate
        if rest is None and gravity:
            # Limp and unsupported, a joint falls until its stop catches it.
            rest = servo.get("min_position_limit" if gravity > 0 else "max_position_limit")
        self.rest = rest  # physical counts (the offset is 0 when this is built)
        self.temperature = temperature
        self.ambient = temperature
        self.speed = 0.0  # counts/s
        self.setpoint = 0.0  # position mode: the profile point, present frame
        self.droop = 0.0  # counts the shaft currently sits short of the setpoint
        self.load = 0.0  # signed effort, per mille
        self.moving = False
        self._overload_for = 0.0

    # -- frames -----------------------------------------------------------------

    def present(self) -> float:
        return (self.servo.actual - self.servo.get("homing_offset")) % 4096

    def present_counts(self) -> int:
        return round(self.present()) % 4096

    def frame_changed(self) -> None:
        """The shaft or the offset moved under the servo: plan again from where it is."""
        self.setpoint = self.present() + self.droop

    def torque_on(self) -> None:
        # The servo plans from where the shaft is: it does not snap, it drives
        # to whatever goal the register holds (why goals are seeded first).
        self.reset_motion()
        self.setpoint = self.present()

    def reset_motion(self) -> None:
        self.speed = self.droop = self.load = self._overload_for = 0.0

    # -- stepping ---------------------------------------------------------------

    def step(self, dt: float) -> None:
        if dt <= 0:
            return
        n = math.ceil(dt / SUBSTEP)
        for _ in range(n):
            self._tick(dt / n)

    def _tick(self, h: float) -> None:
        if not self.servo.torque:
            self._limp(h)
        elif self.servo.get("operating_mode") == ct.OperatingMode.VELOCITY:
            self._spin(h)
        else:
            self._hold(h)
        self._heat(h)

    def _accel(self) -> float:
        units = self.servo.get("acceleration")
        return units * ACCEL_UNIT if units else math.inf

    def _hold(self, h: float) -> None:
        s = self.servo
        goal = float(s.get("goal_position"))
        lo, hi = s.get("min_position_limit"), s.get("max_position_limit")
        if lo or hi:  # both 0 means "no limits" on Feetech servos
            goal = _clamp(goal, lo, hi)  # the servo clamps, whatever the client asked
        vmax = min(abs(s.get("goal_speed")) or MAX_SPEED, MAX_SPEED)
        accel = self._accel()
        d = goal - self.setpoint
        want = math.copysign(min(vmax, abs(d) / h), d)
        if accel < math.inf:
            # Brake in time: never faster than what can still stop at the goal.
            want = math.copysign(min(abs(want), math.sqrt(2 * accel * abs(d))), d)
            self.speed += _clamp(want - self.speed, -accel * h, accel * h)
        else:
            self.speed = want
        self.setpoint += self.speed * h
        if abs(goal - self.setpoint) < 0.05 and abs(self.speed) <= accel * h + 1e-9:
            self.setpoint, self.speed = goal, 0.0
        p = max(s.get("p_coefficient"), 1)
        target = self.gravity * DROOP_K / p
        self.droop += (target - self.droop) * min(1.0, h / DROOP_TAU)
        self.load = p * self.droop / DROOP_K  # = gravity once settled
        s.actual = (self.setpoint - self.droop + s.get("homing_offset")) % 4096
        self.moving = abs(self.speed) > 0.5 or abs(goal - self.setpoint) > 0.5
        self._check_overload(h)

    def _spin(self, h: float) -> None:
        s = self.servo
        want = _clamp(s.get("goal_speed"), -MAX_SPEED, MAX_SPEED)
        accel = self._accel()
        self.speed += _clamp(want - self.speed, -accel * h, accel * h)
        s.actual = (s.actual + self.speed * h) % 4096
        self.load = self.speed * SPIN_LOAD
        self.moving = abs(self.speed) > 0.5

    def _limp(self, h: float) -> None:
        self.reset_motion()
        s = self.servo
        if self.sag_rate > 0 and self.rest is not None:
            d = (self.rest - s.actual + 2048) % 4096 - 2048  # the short way round
            move = math.copysign(min(abs(d), self.sag_rate * h), d)
            s.actual = (s.actual + move) % 4096
            self.speed = move / h
        self.moving = abs(self.speed) > 0.5

    def _check_overload(self, h: float) -> None:
        mem = self.servo.memory
        if self.servo.latched:
            return
        if abs(self.load) > mem[ADDR_OVERLOAD_TORQUE] * 10:
            self._overload_for += h
            if self._overload_for > mem[ADDR_PROTECTION_TIME] * 0.01:
                self.servo.unload(ServoError.OVERLOAD)
        else:
            self._overload_for = 0.0

    def _heat(self, h: float) -> None:
        excess = max(0.0, abs(self.load) - HEAT_THRESHOLD)
        self.temperature += (HEAT_RATE * excess - (self.temperature - self.ambient) / COOL_TAU) * h
        if self.servo.torque and not self.servo.latched and self._too_hot():
            self.servo.unload(ServoError.OVERHEAT)

    def _too_hot(self) -> bool:
        return self.temperature > self.servo.get("max_temperature_limit")

    def live_errors(self) -> ServoError:
        return ServoError.OVERHEAT if self._too_hot() else ServoError(0)

    # -- what the registers show --------------------------------------------------

    def publish(self) -> None:
        """Copy the shaft's state into the present_* registers (before every read)."""
        s = self.servo
        limit = min(1000, s.get("torque_limit"))
        load = round(_clamp(self.load, -limit, limit))
        s.set("present_position", self.present_counts())
        s.set("present_speed", round(_clamp(self.speed, -32767, 32767)))
        s.set("present_load", load)
        s.set("present_temperature", round(_clamp(self.temperature, 0, 255)))
        s.set("present_current", round(abs(load) * AMPS_PER_LOAD) + (2 if s.torque else 0))
        s.set("moving", int(self.moving))
