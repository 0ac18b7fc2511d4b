"""The service layer: what the API, the WebSocket and the CLI clients can ask of the robot.

These are the runbook's gripper_action_bridge, arm_preset_server and auto_home,
done in one process: each method validates, refuses with a clear reason or acts
through the arm commander, and returns an api_models type, one to one with an
endpoint. Refusals raise :class:`ServiceError` with the HTTP status to use;
nothing changes on a refusal.
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any

from lupin import api_models as m
from lupin.arm import Refused
from lupin.config import ConfigError, lupin_home
from lupin.mux import Twist
from lupin.poses import PoseStore, largest_travel, stream_points
from lupin.trajectory import JointStatus

if TYPE_CHECKING:
    from lupin.daemon import Daemon

# How long set_torque(True) waits for the one-joint-per-tick sequence to finish.
ENABLE_WAIT_S = 2.0


class ServiceError(Exception):
    def __init__(self, code: str, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.code, self.message, self.status = code, message, status


def _refused(exc: Refused) -> ServiceError:
    status = 404 if exc.code == "unknown_joint" else 409
    return ServiceError(exc.code, str(exc), status)


class Services:
    def __init__(self, daemon: Daemon) -> None:
        self.d = daemon
        self.profile = daemon.profile
        self.started = time.monotonic()
        joints = [j.name for j in self.profile.arm.joints]
        self.poses = PoseStore(lupin_home() / "poses.yaml", joints)
        self.gripper = self.profile.arm.gripper

    # -- reads -----------------------------------------------------------------

    def health(self) -> m.HealthResponse:
        bus = self.d.bus
        loop = self.d.loop
        summary: dict[str, object] = {"open": bus is not None}
        if bus is not None:
            summary["failures"] = dict(bus.stats.failures)
            summary["transactions"] = sum(bus.stats.transactions.values())
        if loop is not None:
            summary["missing"] = sorted(i for i, r in loop.readings.items() if r.misses)
        return m.HealthResponse(
            ok=bus is not None and loop is not None and loop.first_state.is_set(),
            profile=self.profile.name,
            bus=summary,
            tick_hz=self.profile.control.tick_hz,
            uptime_s=time.monotonic() - self.started,
        )

    def robot(self) -> m.RobotInfo:
        geo = self.d.geometry
        grip = self.gripper
        return m.RobotInfo(
            profile=self.profile.name,
            description=self.profile.description,
            joints=[
                m.JointInfo(
                    name=g.name,
                    id=g.id,
                    window_deg=g.window_deg,
                    is_gripper=grip is not None and grip.joint == g.name,
                )
                for g in geo.values()
            ],
            gripper=m.GripperInfo(
                joint=grip.joint,
                hmi_open_deg=grip.hmi_open_deg,
                hmi_closed_deg=grip.hmi_closed_deg,
                open_rad=grip.open_rad,
                closed_rad=grip.closed_rad,
            )
            if grip
            else None,
            base=self._base_info(),
            presets=self.list_presets().presets,
            pad_layout=self.d.pad_layout_info(),
            mux_sources=self._mux_state().sources,
            default_speed_deg_s=self.profile.arm.default_speed_deg_s,
            state_hz=self.profile.api.state_hz,
        )

    def _base_info(self) -> m.BaseInfo | None:
        b = self.profile.base
        if b is None:
            return None
        v = b.max_wheel_speed_rad_s * b.wheel_radius_m
        half = b.track_width_m / 2 + (b.wheelbase_m or 0.0) / 2
        return m.BaseInfo(
            kind=b.kind,
            holonomic=b.kind == "mecanum",
            max_linear_m_s=v,
            max_angular_rad_s=v / half,
        )

    def _mux_state(self) -> m.MuxState:
        st = self.d.mux.status(self.d.clock())
        return m.MuxState(
            mode=self.profile.mux.mode,
            active=st.active,
            locked_by=st.locked_by,
            sources={
                n: m.SourceState(
                    priority=s.priority,
                    timeout=s.timeout,
                    age_s=s.age,
                    fresh=s.fresh,
                    masked=s.masked,
                )
                for n, s in st.sources.items()
            },
        )

    def state(self) -> m.RobotState:
        now = self.d.clock()
        arm = self.d.arm
        loop = self.d.loop
        status = arm.traj.status()
        setpoints = arm.traj.sample(now) if arm.seeded else {}
        joints = []
        for name, g in self.d.geometry.items():
            r = loop.readings.get(g.id) if loop else None
            seen = r is not None and r.t > 0
            target = arm.traj.target(name)
            commanded = arm.commanded.get(name) if arm.commanded else None
            joints.append(
                m.JointState(
                    name=name,
                    id=g.id,
                    position_deg=math.degrees(g.counts_to_rad(r.position)) if seen and r else None,
                    velocity_deg_s=(
                        math.degrees(g.sign * r.speed * 2 * math.pi / 4096) if seen and r else None
                    ),
                    load=r.load if seen and r else None,
                    temperature_c=r.temperature_c if r else None,
                    voltage_v=r.voltage_v if r else None,
                    commanded_deg=math.degrees(commanded) if commanded is not None else None,
                    target_deg=math.degrees(target) if target is not None else None,
                    setpoint_deg=math.degrees(setpoints[name]) if name in setpoints else None,
                    status="stalled"
                    if name in arm.stalled
                    else (status.get(name) or JointStatus.IDLE).value,
                    torque=arm.torque[name].value,
                    excluded=arm.excluded.get(name),
                    error_bits=r.error if r else 0,
                    stale=bool(r.misses) if r else True,
                )
            )
        base = None
        if self.d.base is not None and loop is not None:
            twist = self.d.base.current_twist(now)
            goals = self.d.base.wheel_goals(now)
            blocked = loop.base_blocked()
            base = m.BaseState(
                twist=None
                if twist is None
                else {
                    "linear_x": twist.linear_x,
                    "linear_y": twist.linear_y,
                    "angular_z": twist.angular_z,
                },
                wheels=[
                    m.WheelState(
                        name=w.name,
                        id=w.id,
                        speed_counts_s=loop.readings[w.id].speed
                        if loop.readings[w.id].t > 0
                        else None,
                        goal_counts_s=0 if self.d.estop or blocked else goals.get(w.id, 0),
                        excluded=loop.wheels_excluded.get(w.id),
                        error_bits=loop.readings[w.id].error,
                        stale=bool(loop.readings[w.id].misses),
                    )
                    for w in self.d.base.config.wheels
                ],
                blocked=blocked,
            )
        return m.RobotState(
            t=now,
            joints=joints,
            torque=arm.torque_summary.value,
            estop=self.d.estop,
            seeded=arm.seeded,
            mux=self._mux_state(),
            base=base,
            pad=m.PadState.model_validate(self.d.pad_state()),
            events=[
                m.StallEvent(
                    t=e.t,
                    joint=e.joint,
                    error_deg=math.degrees(e.error_rad) if math.isfinite(e.error_rad) else -1.0,
                    diagnosis=e.diagnosis,
                )
                for e in self.d.stalls.events
            ],
        )

    def telemetry(self) -> dict[str, Any]:
        loop, bus = self.d.loop, self.d.bus
        st = self.d.mux.status(self.d.clock())
        return {
            "tick_periods": list(loop.stats.periods) if loop else [],
            "tick_durations": list(loop.stats.durations) if loop else [],
            "tick_overruns": loop.stats.overruns if loop else 0,
            "ticks": loop.stats.ticks if loop else 0,
            "bus_transactions": dict(bus.stats.transactions) if bus else {},
            "bus_failures": dict(bus.stats.failures) if bus else {},
            "mux_active": st.active,
            "mux_sources": list(st.sources),
            "estop": self.d.estop,
        }

    # -- base and E-stop ---------------------------------------------------------

    def submit_twist(self, req: m.TwistRequest) -> m.Ok:
        if req.source not in self.d.mux_sources():
            raise ServiceError("unknown_source", f"source {req.source!r} is not in this mux", 404)
        self.d.submit_twist(req.source, Twist(req.linear_x, req.linear_y, req.angular_z))
        return m.Ok()

    async def set_estop(self, req: m.EstopRequest) -> m.EstopResponse:
        await self.d.set_estop(req.engaged)
        return m.EstopResponse(engaged=self.d.estop)

    # -- arm -------------------------------------------------------------------------

    def _move(self, targets: dict[str, float], travel: float) -> m.MoveResponse:
        try:
            result = self.d.arm.move(targets, travel, self.d.clock())
        except Refused as exc:
            raise _refused(exc) from None
        return m.MoveResponse(
            targets_deg={n: math.degrees(v) for n, v in result.targets.items()},
            travel_s=result.duration,
        )

    def _travel(self, deltas_rad: list[float], speed_rad_s: float) -> float:
        # The runbook's rate slider: slew speed, not torque; never under 0.1 s.
        return max(0.1, max(deltas_rad, default=0.0) / speed_rad_s)

    def _joint(self, joint: str) -> None:
        if joint not in self.d.geometry:
            raise ServiceError("unknown_joint", f"unknown joint {joint!r}", 404)

    async def set_joint(self, joint: str, req: m.JointRequest) -> m.MoveResponse:
        self._joint(joint)
        if self.gripper and joint == self.gripper.joint:
            raise ServiceError("use_gripper", "the gripper moves through /api/arm/gripper", 400)
        lo, hi = self.d.geometry[joint].window_deg
        if not lo <= req.angle_deg <= hi:
            raise ServiceError(
                "out_of_window", f"{joint}: {req.angle_deg} deg is outside [{lo}, {hi}]", 400
            )
        self._check(joint)
        target = math.radians(req.angle_deg)
        speed = math.radians(req.speed_deg_s or self.profile.arm.default_speed_deg_s)
        assert self.d.arm.commanded is not None
        delta = abs(target - self.d.arm.commanded[joint])
        return self._move({joint: target}, self._travel([delta], speed))

    def _check(self, joint: str) -> None:
        try:
            self.d.arm.check_can_move([joint])
        except Refused as exc:
            raise _refused(exc) from None

    async def set_gripper(self, req: m.JointRequest) -> m.MoveResponse:
        g = self.gripper
        if g is None:
            raise ServiceError("no_gripper", "this robot has no gripper", 404)
        lo, hi = sorted((g.hmi_open_deg, g.hmi_closed_deg))
        if not lo <= req.angle_deg <= hi:
            raise ServiceError(
                "out_of_window", f"gripper: {req.angle_deg} deg is outside [{lo}, {hi}]", 400
            )
        self._check(g.joint)
        # HMI degrees map linearly onto the joint: open end to open_rad, closed to closed_rad.
        f = (req.angle_deg - g.hmi_open_deg) / (g.hmi_closed_deg - g.hmi_open_deg)
        target = g.open_rad + f * (g.closed_rad - g.open_rad)
        rad_per_hmi_deg = abs(g.closed_rad - g.open_rad) / abs(g.hmi_closed_deg - g.hmi_open_deg)
        speed = (req.speed_deg_s or self.profile.arm.default_speed_deg_s) * rad_per_hmi_deg
        assert self.d.arm.commanded is not None
        delta = abs(target - self.d.arm.commanded[g.joint])
        reply = self._move({g.joint: target}, self._travel([delta], speed))
        return m.MoveResponse(targets_deg={g.joint: req.angle_deg}, travel_s=reply.travel_s)

    async def set_torque(self, req: m.TorqueRequest) -> m.TorqueResponse:
        if not req.enabled:
            await self.d.disable_torque()
            return m.TorqueResponse(torque=self.d.arm.torque_summary.value)
        if self.d.estop:
            raise ServiceError("estop", "the E-stop is engaged: release it before torque on", 409)
        if not self.d.arm.seeded:
            raise ServiceError("not_seeded", "joint not seeded: no complete joint state yet", 409)
        await self.d.enable_torque()
        await self.d.wait_torque_on(ENABLE_WAIT_S)
        return m.TorqueResponse(torque=self.d.arm.torque_summary.value)

    def _arm_joints(self) -> list[str]:
        grip = self.gripper.joint if self.gripper else None
        return [n for n in self.d.geometry if n != grip]

    def _pose_move(self, pose_rad: dict[str, float], travel: float) -> m.MoveResponse:
        clamped = {n: self.d.geometry[n].clamp_rad(v) for n, v in pose_rad.items()}
        return self._move(clamped, travel)

    async def init_arm(self) -> m.MoveResponse:
        return self._pose_move(
            dict.fromkeys(self._arm_joints(), 0.0), self.profile.arm.init_travel_s
        )

    def list_presets(self) -> m.PresetList:
        return m.PresetList(
            presets={
                name: {j: math.degrees(v) for j, v in pose.items()}
                for name, pose in self.profile.presets.items()
            }
        )

    async def go_preset(self, name: str) -> m.MoveResponse:
        pose = self.profile.presets.get(name)
        if pose is None:
            known = ", ".join(self.profile.presets)
            raise ServiceError("unknown_preset", f"unknown preset {name!r} (known: {known})", 404)
        return self._pose_move(dict(pose), self.profile.arm.preset_travel_s)

    # -- taught poses -------------------------------------------------------------------

    def _load_poses(self) -> dict[str, dict[str, float]]:
        try:
            return self.poses.load()
        except ConfigError as exc:
            raise ServiceError("bad_pose_file", str(exc), 409) from None

    def list_poses(self) -> m.PoseList:
        here = self.d.arm.measured
        out = []
        for name, pose in sorted(self._load_poses().items()):
            dist = largest_travel(here, pose) if all(j in here for j in pose) else None
            out.append(m.Pose(name=name, joints_rad=pose, distance_rad=dist))
        return m.PoseList(poses=out)

    def get_pose(self, name: str) -> m.Pose:
        for pose in self.list_poses().poses:
            if pose.name == name:
                return pose
        raise ServiceError("unknown_pose", f"no taught pose {name!r}", 404)

    async def save_pose(self, name: str, req: m.PoseSaveRequest) -> m.Pose:
        if req.joints_rad is not None:
            unknown = sorted(set(req.joints_rad) - set(self.d.geometry))
            if unknown:
                raise ServiceError("unknown_joint", f"unknown joints {unknown}", 404)
            pose = dict(req.joints_rad)
        else:
            if not self.d.arm.seeded:
                raise ServiceError("not_seeded", "no complete joint state to capture yet", 409)
            pose = {n: self.d.arm.measured[n] for n in self._arm_joints()}
        try:
            self.poses.put(name, pose)
        except ValueError as exc:
            raise ServiceError("bad_name", str(exc), 400) from None
        return self.get_pose(name)

    def delete_pose(self, name: str) -> m.Ok:
        self._load_poses()
        if not self.poses.delete(name):
            raise ServiceError("unknown_pose", f"no taught pose {name!r}", 404)
        return m.Ok()

    async def go_pose(self, name: str, req: m.PoseGoRequest) -> m.PoseGoResponse:
        pose = self._load_poses().get(name)
        if pose is None:
            raise ServiceError("unknown_pose", f"no taught pose {name!r}", 404)
        if not pose:
            # A hand-edited poses.yaml can still hold one (the API refuses to teach it):
            # with no joint named the torque check below passes vacuously, and the empty
            # trajectory was a 500. Refuse it by name instead.
            raise ServiceError("empty_pose", f"taught pose {name!r} names no joint", 409)
        arm = self.d.arm
        try:
            arm.check_can_move(list(pose))
        except Refused as exc:
            raise _refused(exc) from None
        assert arm.commanded is not None
        goal = {j: self.d.geometry[j].clamp_rad(v) for j, v in pose.items()}
        start = {j: arm.commanded[j] for j in goal}
        travel = largest_travel(start, goal)
        if travel > req.max_travel_rad:
            raise ServiceError(
                "too_far",
                f"largest joint travel {travel:.3f} rad exceeds max_travel {req.max_travel_rad}"
                " rad; raise it deliberately for a known-long move",
                409,
            )
        points = stream_points(start, goal, req.speed_rad_s)
        try:
            arm.stream(points, self.d.clock())
        except Refused as exc:
            raise _refused(exc) from None
        return m.PoseGoResponse(
            name=name, largest_travel_rad=travel, travel_s=points[-1].time_from_start
        )

    async def heal(self) -> m.HealResponse:
        report = await self.d.heal()
        return m.HealResponse(
            result=report.result, details=report.details, auto_home=self.d.auto_home_state
        )
