"""Pad teleop, pure: the dead-man base teleop and the open-loop arm integrator.

Nothing here sleeps or does I/O; every call takes ``now``. The pad task
(:mod:`lupin.pad_task`) feeds frames and calls the timers.

Base rules (teleop_twist_joy + joy, and the runbook's reasons):

* Xbox: LB (the dead-man) must be held to drive; RB is turbo, only with LB held.
* On release exactly ONE zero twist, then silence. Not a stream of zeros: zeros
  would keep the `joy` source (priority 100) fresh forever and starve the
  autonomy stack and the HMI (runbook, "Why the dead-man makes priority honest").
* A vanished pad counts as a release; after it returns nothing moves until LB is
  pressed afresh, and a stick deflected at the press moves nothing until it has
  been back to neutral.
* While engaged the last twist is re-published at ``autorepeat_rate`` (20 Hz) even
  without new frames, so the 0.3 s joy timeout never fires during a steady hold.
* DS4 (``require_enable_button: false``): publishes to `manual` while a stick is
  deflected, one zero on return to neutral, then silence.
* A NaN/inf or out-of-range axis reads as neutral and is counted; never a crash.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from lupin.arm import ArmCommander, MoveResult, Refused
from lupin.config_models import GripperConfig
from lupin.mux import ZERO_TWIST, Twist
from lupin.pad import PadFrame, apply_deadzone
from lupin.pad_mapping import ArmControl, ArmRole, PadMapping

log = logging.getLogger(__name__)

# Tolerance for an axis reading just past ±1 (float noise from normalisation).
AXIS_EPS = 1e-3
TRANSLATE, YAW = "translate", "yaw"


@dataclass(frozen=True, slots=True)
class Publish:
    """Publish ``twist`` on the mux source ``source``.

    Every teleop call returns ``Publish | None``; None means publish NOTHING,
    which is how the dead-man falls silent.
    """

    source: str
    twist: Twist


def read_axis(frame: PadFrame, index: int) -> tuple[float, bool]:
    """(value, ok): an unused index (-1) reads 0; NaN/inf/out of range reads 0 and not ok."""
    if index < 0:
        return 0.0, True
    value = frame.axis(index)
    if not math.isfinite(value) or abs(value) > 1.0 + AXIS_EPS:
        return 0.0, False
    return max(-1.0, min(1.0, value)), True


class BaseTeleop:
    """Pad frames -> twists for the mux (or nothing). See the module docstring."""

    def __init__(self, mapping: PadMapping) -> None:
        self.mapping = mapping
        self.source = mapping.source
        self.period = 1.0 / mapping.autorepeat_rate
        self.engaged = False  # publishing: the dead-man is held and armed (DS4: deflected)
        self.deadman_held = False
        self.bad_axes = 0  # NaN/inf/out-of-range axis readings, each counted once per frame
        # Start as after a vanish: a pad held at start-up must be pressed afresh.
        self._rearm = True
        self._blocked: set[str] = set()
        self._last: Publish | None = None
        self._last_at = -math.inf

    # -- inputs ------------------------------------------------------------------------

    def update(self, frame: PadFrame | None, now: float) -> Publish | None:
        """A new frame (None = the pad vanished). Returns what to publish now, if anything."""
        if frame is None:
            self.deadman_held = False
            self._rearm = True
            return self._release(now)
        sticks = self._sticks(frame)
        deflected = {TRANSLATE: sticks[0] != 0 or sticks[1] != 0, YAW: sticks[2] != 0}
        if self.mapping.require_enable_button:
            return self._update_deadman(frame, sticks, deflected, now)
        return self._update_free(frame, sticks, deflected, now)

    def tick(self, now: float) -> Publish | None:
        """The autorepeat: re-publish the last twist once per period while engaged."""
        if not self.engaged or self._last is None or now < self._last_at + self.period - 1e-9:
            return None
        self._last_at = now
        return self._last

    def next_due(self) -> float | None:
        """When :meth:`tick` next has something to do; None while silent."""
        return self._last_at + self.period if self.engaged else None

    # -- the two gating modes ------------------------------------------------------

    def _update_deadman(
        self,
        frame: PadFrame,
        sticks: tuple[float, float, float],
        deflected: dict[str, bool],
        now: float,
    ) -> Publish | None:
        held = frame.button(self.mapping.enable_button)
        self.deadman_held = held
        if not held:
            self._rearm = False
            return self._release(now)
        if self._rearm:
            return None  # held since before a vanish (or start-up): not a fresh press
        if not self.engaged:
            self.engaged = True
            # A stick already deflected at the press must not lurch the base.
            self._blocked = {g for g, d in deflected.items() if d}
        self._blocked -= {g for g, d in deflected.items() if not d}
        return self._publish(self._twist(frame, sticks), now)

    def _update_free(
        self,
        frame: PadFrame,
        sticks: tuple[float, float, float],
        deflected: dict[str, bool],
        now: float,
    ) -> Publish | None:
        moving = any(deflected.values())
        if self._rearm:
            if moving:
                return None  # deflected since before a vanish: wait for neutral
            self._rearm = False
        if moving:
            self.engaged = True
            return self._publish(self._twist(frame, sticks), now)
        return self._release(now)

    # -- helpers -------------------------------------------------------------------------

    def _sticks(self, frame: PadFrame) -> tuple[float, float, float]:
        m = self.mapping
        out = []
        for index in (m.axis_linear.x, m.axis_linear.y, m.axis_angular.yaw):
            value, ok = read_axis(frame, index)
            if not ok:
                self.bad_axes += 1
            out.append(apply_deadzone(value, m.deadzone))
        return out[0], out[1], out[2]

    def _twist(self, frame: PadFrame, sticks: tuple[float, float, float]) -> Twist:
        m = self.mapping
        # Turbo only ever multiplies a drive the dead-man already allows.
        turbo = frame.button(m.enable_turbo_button)
        lin = m.scale_linear_turbo if turbo else m.scale_linear
        ang = m.scale_angular_turbo if turbo else m.scale_angular
        x, y, yaw = sticks
        if TRANSLATE in self._blocked:
            x = y = 0.0
        if YAW in self._blocked:
            yaw = 0.0
        # `+ 0.0` turns a -0.0 (negative scale times 0) into a plain zero.
        return Twist(lin.x * x + 0.0, lin.y * y + 0.0, ang.yaw * yaw + 0.0)

    def _publish(self, twist: Twist, now: float) -> Publish:
        self._last = Publish(self.source, twist)
        self._last_at = now
        return self._last

    def _release(self, now: float) -> Publish | None:
        """Exactly one zero if we were publishing, then silence."""
        self._blocked = set()
        if not self.engaged:
            return None
        self.engaged = False
        self._last = None
        self._last_at = now
        return Publish(self.source, ZERO_TWIST)


# -- the arm integrator -----------------------------------------------------------------

# Profile-agnostic roles onto the profile's joint names (so101 vs mecanum); a profile
# without a role's joint simply leaves that control inert.
ROLE_JOINT_ALIASES: dict[ArmRole, tuple[str, ...]] = {
    "shoulder_pan": ("shoulder_pan",),
    "shoulder_lift": ("shoulder_lift",),
    "elbow": ("elbow", "elbow_flex"),
    "wrist": ("wrist", "wrist_flex"),
    "wrist_roll": ("wrist_roll", "wrist_rotate"),
}
SHOULDER_ROLES: frozenset[ArmRole] = frozenset({"shoulder_pan", "shoulder_lift"})
DPAD_THRESHOLD = 0.5  # a D-pad axis reads -1/0/+1; anything past half is a press
GRIPPER_DEADBAND = 0.1  # net trigger pull below this holds the jaw (trigger jitter)
TRIGGERS = ("open", "close")


def resolve_roles(joint_names: Sequence[str]) -> dict[ArmRole, str]:
    """Each role's joint in this profile, by the first alias present."""
    out: dict[ArmRole, str] = {}
    for role, aliases in ROLE_JOINT_ALIASES.items():
        joint = next((a for a in aliases if a in joint_names), None)
        if joint is not None:
            out[role] = joint
    return out


def trigger_pull(value: float, rest: float, full: float) -> float:
    """pull = clamp((v - rest) / (full - rest), 0, 1): rest/full are measured per transport."""
    return max(0.0, min(1.0, (value - rest) / (full - rest)))


class ArmTeleop:
    """arm_teleop: an open-loop integrator from held controls to joint targets.

    Each :meth:`step` (``update_rate_hz``, 10 Hz) advances every held control's
    joint by ``step_rad`` (0.15), clamped to the joint's window, and returns the
    targets to hand to ``ArmCommander.move(targets, duration, now)``.
    """

    def __init__(
        self,
        mapping: PadMapping,
        joint_names: Sequence[str],
        windows: Mapping[str, tuple[float, float]],
        *,
        gripper: GripperConfig | None = None,
        log_every: float = 5.0,
    ) -> None:
        self.mapping = mapping
        self.duration = 1.0 / mapping.update_rate_hz
        self.windows = dict(windows)
        self.gripper = gripper
        self.gripper_joint = gripper.joint if gripper is not None else None
        self.arm_joints = [n for n in joint_names if n != self.gripper_joint]
        roles = resolve_roles(self.arm_joints)
        self.controls = {roles[r]: (r, c) for r, c in mapping.arm_controls.items() if r in roles}
        self.commanded: dict[str, float] = {}
        self.active: set[str] = set()
        self.refusals = 0
        self.last_refusal: str | None = None
        self._held: dict[str, int] = {}
        self._tapped: dict[str, int] = {}  # presses since the last step: a quick tap still steps
        self._shoulder_live = True
        self._pull = dict.fromkeys(TRIGGERS, 0.0)
        self._trigger_ready = self._fresh_trigger_guard()
        self._log_every = log_every
        self._logged: dict[str, float] = {}

    # -- inputs ------------------------------------------------------------------------

    def on_frame(self, frame: PadFrame | None) -> None:
        """Latch the controls from a frame; None (the pad vanished) releases everything."""
        if frame is None:
            self._held = {}
            self._pull = dict.fromkeys(TRIGGERS, 0.0)
            # A returning pad may report the bogus pre-event 0.0 again.
            self._trigger_ready = self._fresh_trigger_guard()
            return
        # shoulder_live = not disable_held: the face buttons never move the shoulder
        # while LB drives the base (runbook, the two de-confliction decisions).
        self._shoulder_live = not frame.button(self.mapping.shoulder_disable_button)
        for joint, (role, control) in self.controls.items():
            d = self._direction(control, frame)
            if role in SHOULDER_ROLES and not self._shoulder_live:
                d = 0
            self._held[joint] = d
            if d:
                self._tapped[joint] = d
        for side in TRIGGERS:
            self._pull[side] = self._trigger(side, frame)

    @property
    def wants_tick(self) -> bool:
        """True while a step would do something (or must close an active edge)."""
        return bool(any(self._held.values()) or self._tapped or self.active or self._gripper_dir())

    # -- the integrator -----------------------------------------------------------------

    def step(self, measured: Mapping[str, float], now: float) -> dict[str, float]:
        """One 10 Hz tick: targets (rad) for the joints that move this tick."""
        targets: dict[str, float] = {}
        tapped, self._tapped = self._tapped, {}
        # The seed gate: nothing until every arm joint has been observed.
        if all(n in measured for n in self.arm_joints):
            for joint, (role, _) in self.controls.items():
                d = self._held.get(joint) or tapped.get(joint, 0)
                if role in SHOULDER_ROLES and not self._shoulder_live:
                    d = 0
                self._advance(joint, d, measured, targets)
        g = self.gripper_joint
        # The gripper is held until it has been observed, like the arm seed gate.
        if g is not None and g in measured:
            self._advance(g, self._gripper_dir(), measured, targets)
        return targets

    def send(self, arm: ArmCommander, now: float) -> MoveResult | None:
        """Step and hand the targets to the arm commander; a refusal drops the step."""
        targets = self.step(arm.measured, now)
        if not targets:
            return None
        try:
            return arm.move(targets, self.duration, now)
        except Refused as exc:
            self.refusals += 1
            self.last_refusal = str(exc)
            # Dropped: the next active tick re-seeds from measured, so the integrator
            # never runs ahead of an arm that did not move.
            self.active -= set(targets)
            if now - self._logged.get(exc.code, -math.inf) >= self._log_every:
                self._logged[exc.code] = now
                log.warning("arm teleop: step refused (%s); %d so far", exc, self.refusals)
            return None

    def _advance(
        self, joint: str, d: float, measured: Mapping[str, float], out: dict[str, float]
    ) -> None:
        if not d:
            self.active.discard(joint)
            return
        if joint not in self.active:
            # Re-seed on the idle->active edge from MEASURED state, so a tap is one
            # clean step and not a jump from a gravity-sagged setpoint.
            self.commanded[joint] = measured[joint]
            self.active.add(joint)
        lo, hi = self._limits(joint)
        value = self.commanded[joint] + d * self.mapping.step_rad
        self.commanded[joint] = max(lo, min(hi, value))
        out[joint] = self.commanded[joint]

    def _limits(self, joint: str) -> tuple[float, float]:
        lo, hi = self.windows.get(joint, (-math.inf, math.inf))
        if joint == self.gripper_joint and self.gripper is not None:
            g = self.gripper
            lo = max(lo, min(g.open_rad, g.closed_rad))
            hi = min(hi, max(g.open_rad, g.closed_rad))
        return lo, hi

    # -- controls ------------------------------------------------------------------------

    @staticmethod
    def _direction(control: ArmControl, frame: PadFrame) -> int:
        if control.axis is None:
            plus = frame.button(control.plus_button if control.plus_button is not None else -1)
            minus = frame.button(control.minus_button if control.minus_button is not None else -1)
            return int(plus) - int(minus)
        value, _ = read_axis(frame, control.axis)
        pressed = 1 if value > DPAD_THRESHOLD else -1 if value < -DPAD_THRESHOLD else 0
        return pressed * control.sign

    def _fresh_trigger_guard(self) -> dict[str, bool]:
        # With rest near 0 there is no ambiguity, so the axis initialises at once.
        m = self.mapping
        return {s: abs(getattr(m, f"gripper_{s}_rest")) < 0.5 for s in TRIGGERS}

    def _trigger(self, side: str, frame: PadFrame) -> float:
        m = self.mapping
        axis = getattr(m, f"gripper_{side}_axis")
        if not getattr(m, f"gripper_{side}_enabled") or axis < 0:
            return 0.0
        value, ok = read_axis(frame, axis)
        if not ok:
            return 0.0
        if not self._trigger_ready[side]:
            # The _trigger_init guard: some drivers report 0.0 before the first
            # physical event; with rest near ±1 that would read as a half pull.
            if value == 0.0:
                return 0.0
            self._trigger_ready[side] = True
        rest, full = getattr(m, f"gripper_{side}_rest"), getattr(m, f"gripper_{side}_full")
        return trigger_pull(value, rest, full)

    def _gripper_dir(self) -> float:
        """Signed rate in units of step_rad: + moves toward open_rad, - toward closed_rad."""
        if self.gripper is None:
            return 0.0
        net = self._pull["open"] - self._pull["close"]
        if abs(net) < GRIPPER_DEADBAND:
            return 0.0
        toward_open = 1.0 if self.gripper.open_rad > self.gripper.closed_rad else -1.0
        return net * toward_open


__all__ = [
    "AXIS_EPS",
    "ROLE_JOINT_ALIASES",
    "ArmTeleop",
    "BaseTeleop",
    "Publish",
    "read_axis",
    "resolve_roles",
    "trigger_pull",
]
