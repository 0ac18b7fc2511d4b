"""The joint trajectory interpolator, driven by a fake clock (plain floats)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lupin.trajectory import JointStatus, JointTrajectoryInterpolator, TrajectoryPoint

DT = 1e-6  # finite-difference step (s)


def interp(**kw: float) -> JointTrajectoryInterpolator:
    ti = JointTrajectoryInterpolator(["a", "b"], **kw)
    ti.seed({"a": 0.0, "b": 1.0})
    return ti


def goal(t: float, **positions: float) -> TrajectoryPoint:
    return TrajectoryPoint(positions=positions, time_from_start=t)


def fd_velocity(ti: JointTrajectoryInterpolator, joint: str, t: float) -> tuple[float, float]:
    """One-sided finite-difference velocities just before and just after ``t``."""
    before = (ti.sample(t)[joint] - ti.sample(t - DT)[joint]) / DT
    after = (ti.sample(t + DT)[joint] - ti.sample(t)[joint]) / DT
    return before, after


# -- seeding and simple moves ------------------------------------------------------------


def test_nothing_is_sampled_before_seeding() -> None:
    ti = JointTrajectoryInterpolator(["a", "b"])
    assert ti.sample(0.0) == {}
    ti.seed({"a": 0.3})
    assert ti.sample(5.0) == {"a": 0.3}
    assert ti.status() == {"a": JointStatus.IDLE, "b": JointStatus.IDLE}
    with pytest.raises(ValueError, match="joint 'b' is not seeded"):
        ti.set_goal([goal(1.0, b=0.5)], 0.0)


def test_single_point_move_starts_and_ends_at_rest_and_holds() -> None:
    ti = interp()
    ti.set_goal([goal(2.0, a=1.0)], 10.0)
    assert ti.sample(10.0)["a"] == 0.0
    assert ti.sample(11.0)["a"] == pytest.approx(0.5)  # symmetric ease-in/ease-out
    assert ti.sample(12.0)["a"] == pytest.approx(1.0)
    assert ti.sample(99.0)["a"] == 1.0  # holds the last point
    assert ti.sample_velocity(10.0)["a"] == 0.0 and ti.sample_velocity(12.0)["a"] == 0.0
    assert ti.active(11.9) and not ti.active(12.0)
    assert ti.target("a") == 1.0 and ti.end_time("a") == 12.0
    assert ti.sample(11.0)["b"] == 1.0  # not named: untouched


def test_waypoints_are_hit_with_continuous_velocity_and_no_overshoot() -> None:
    ti = interp()
    pts = [goal(1.0, a=0.5), goal(2.0, a=1.2), goal(3.0, a=1.0), goal(4.0, a=1.0)]
    ti.set_goal(pts, 0.0)
    for p in pts:
        assert ti.sample(p.time_from_start)["a"] == pytest.approx(p.positions["a"])
    for t in (1.0, 2.0, 3.0):
        before, after = fd_velocity(ti, "a", t)
        assert before == pytest.approx(after, abs=1e-4)
        assert ti.sample_velocity(t)["a"] == pytest.approx(before, abs=1e-4)
    assert ti.sample_velocity(2.0)["a"] == 0.0  # 1.2 is a turning point: stays the peak
    peak = max(ti.sample(i / 1000)["a"] for i in range(4001))
    assert peak == pytest.approx(1.2)
    assert ti.sample_velocity(3.0)["a"] == 0.0  # flat to the last point


def test_given_velocities_are_used() -> None:
    ti = interp()
    pts = [
        TrajectoryPoint({"a": 0.5}, 1.0, velocities={"a": 0.8}),
        TrajectoryPoint({"a": 1.0}, 2.0, velocities={"a": 0.2}),
    ]
    ti.set_goal(pts, 0.0)
    assert ti.sample_velocity(1.0)["a"] == pytest.approx(0.8)
    assert fd_velocity(ti, "a", 1.0)[0] == pytest.approx(0.8, abs=1e-4)
    assert ti.sample_velocity(2.0 - 1e-9)["a"] == pytest.approx(0.2, abs=1e-6)


# -- replacement and partial goals ---------------------------------------------------------


def test_replacement_mid_motion_is_position_and_velocity_continuous() -> None:
    ti = interp()
    ti.set_goal([goal(2.0, a=1.0)], 0.0)
    t = 0.7
    p_old = ti.sample(t)["a"]
    v_old_fd = (ti.sample(t)["a"] - ti.sample(t - DT)["a"]) / DT
    assert v_old_fd > 0.3  # it is really moving
    ti.set_goal([goal(1.0, a=-0.5)], t)  # reverse mid-motion
    assert ti.sample(t)["a"] == p_old
    v_new_fd = (ti.sample(t + DT)["a"] - ti.sample(t)["a"]) / DT
    assert v_new_fd == pytest.approx(v_old_fd, abs=1e-4)  # no velocity jump
    assert ti.sample(t + 1.0)["a"] == pytest.approx(-0.5)


def test_replacing_one_joint_leaves_the_others_motion_intact() -> None:
    ti, ref = interp(), interp()
    for x in (ti, ref):
        x.set_goal([goal(2.0, a=1.0, b=0.0)], 0.0)
    ti.set_goal([goal(1.0, a=0.2)], 0.5)
    for i in range(31):
        t = i / 10
        assert ti.sample(t)["b"] == ref.sample(t)["b"]
    assert ti.sample(1.5)["a"] == pytest.approx(0.2)
    assert ti.target("a") == 0.2 and ti.target("b") == 0.0


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(0.05, 1.0),  # wait before the next goal
            st.floats(-2.0, 2.0),  # position
            st.floats(0.1, 2.0),  # duration
        ),
        min_size=1,
        max_size=6,
    )
)
def test_any_sequence_of_replacements_is_c1(goals: list[tuple[float, float, float]]) -> None:
    ti, now = interp(), 0.0
    for wait, pos, duration in goals:
        now += wait
        p_before = ti.sample(now)["a"]
        v_before = ti.sample_velocity(now)["a"]
        ti.set_goal([goal(duration, a=pos)], now)
        assert ti.sample(now)["a"] == p_before
        assert ti.sample_velocity(now)["a"] == v_before
        step = 1e-8  # accelerations reach ~1e3 rad/s^2 on short goals
        fd_after = (ti.sample(now + step)["a"] - ti.sample(now)["a"]) / step
        assert fd_after == pytest.approx(v_before, abs=1e-3 * (1 + abs(v_before)))
    assert ti.sample(now + 10.0)["a"] == goals[-1][1]


# -- cancel ------------------------------------------------------------------------


def test_cancel_holds_the_measured_position() -> None:
    ti = interp()
    ti.set_goal([goal(2.0, a=1.0, b=0.0)], 0.0)
    ti.cancel({"a": 0.33, "b": 0.9}, 1.0)
    assert ti.sample(1.0) == {"a": 0.33, "b": 0.9}
    assert ti.sample(50.0) == {"a": 0.33, "b": 0.9}
    assert not ti.active(1.0)
    assert ti.status() == {"a": JointStatus.SETTLED, "b": JointStatus.SETTLED}
    assert ti.target("a") == 0.33


def test_cancel_one_joint_and_without_a_measurement() -> None:
    ti = interp()
    ti.set_goal([goal(2.0, a=1.0, b=0.0)], 0.0)
    commanded_b = ti.sample(1.0)["b"]
    ti.cancel({"a": 0.3}, 1.0, joints=["b"])  # b has no measurement: holds its setpoint
    assert ti.sample(3.0)["b"] == commanded_b
    assert ti.sample(3.0)["a"] == 1.0  # a keeps moving to its goal
    assert ti.status()["b"] is JointStatus.MOVING  # still supervised against the hold
    with pytest.raises(ValueError, match="unknown joint 'c'"):
        ti.cancel({}, 1.0, joints=["c"])


# -- supervision ---------------------------------------------------------------------------


def test_settles_only_after_the_end_within_tolerance() -> None:
    ti = interp(goal_tolerance=0.02)
    ti.set_goal([goal(1.0, a=0.01)], 0.0)
    ti.update_measured({"a": 0.01}, 0.5)  # already there, but the trajectory is running
    assert ti.status()["a"] is JointStatus.MOVING
    ti.update_measured({"a": 0.035}, 1.0)  # 0.025 off: not yet
    assert ti.status()["a"] is JointStatus.MOVING
    ti.update_measured({"a": 0.029}, 1.1)
    assert ti.status()["a"] is JointStatus.SETTLED
    assert ti.lag("a") == pytest.approx(0.019)


def test_follows_the_setpoint_and_settles() -> None:
    ti = interp()
    ti.set_goal([goal(2.0, a=1.0)], 0.0)
    for i in range(31):
        t = i / 10
        ti.update_measured({"a": ti.sample(t)["a"] - 0.01, "b": 1.0}, t)
    assert ti.status() == {"a": JointStatus.SETTLED, "b": JointStatus.IDLE}


def test_stalled_by_sustained_lag() -> None:
    ti = interp(stall_lag=0.15, stall_time=0.5)
    ti.set_goal([goal(2.0, a=1.0)], 0.0)
    t, first_over = 0.0, None
    while ti.status()["a"] is JointStatus.MOVING:
        ti.update_measured({"a": 0.0}, t)  # the servo does not move at all
        lag = ti.lag("a")
        assert lag is not None
        if first_over is None and lag > 0.15:
            first_over = t
        t = round(t + 0.01, 6)
    assert first_over is not None
    assert ti.status()["a"] is JointStatus.STALLED and ti.stall_reason("a") == "lag"
    assert t - 0.01 == pytest.approx(first_over + 0.5)


def test_a_short_lag_spike_is_not_a_stall() -> None:
    ti = interp(stall_lag=0.15, stall_time=0.5)
    ti.set_goal([goal(2.0, a=1.0)], 0.0)
    ti.update_measured({"a": ti.sample(0.8)["a"] - 0.2}, 0.8)
    ti.update_measured({"a": ti.sample(1.2)["a"] - 0.05}, 1.2)  # recovered
    ti.update_measured({"a": ti.sample(1.4)["a"] - 0.2}, 1.4)
    assert ti.status()["a"] is JointStatus.MOVING


def test_stalled_when_not_settled_by_end_plus_margin() -> None:
    ti = interp(goal_tolerance=0.02, settle_time_margin=1.0)
    ti.set_goal([goal(2.0, a=1.0)], 0.0)
    ti.update_measured({"a": 0.9}, 3.0)  # 0.1 short: lag under 0.15, just never arrives
    assert ti.status()["a"] is JointStatus.MOVING
    ti.update_measured({"a": 0.9}, 3.01)
    assert ti.status()["a"] is JointStatus.STALLED and ti.stall_reason("a") == "timeout"
    ti.set_goal([goal(1.0, a=0.9)], 3.1)  # a new goal clears it
    assert ti.status()["a"] is JointStatus.MOVING and ti.stall_reason("a") is None


def test_measurement_of_unknown_or_glitched_joints_is_skipped() -> None:
    ti = interp()
    ti.update_measured({"gripper": 0.1, "a": math.nan}, 0.0)
    assert ti.lag("a") is None
    with pytest.raises(ValueError, match="unknown joint 'zz'"):
        ti.lag("zz")


# -- validation ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("points", "message"),
    [
        ([], "at least one point"),
        ([goal(1.0)], "at least one joint"),
        ([goal(1.0, elbow=0.1)], "unknown joint 'elbow'"),
        ([goal(0.0, a=0.1)], "time_from_start 0.0 must be greater than 0.0"),
        ([goal(1.0, a=0.1), goal(1.0, a=0.2)], "point 1: time_from_start 1.0"),
        ([goal(2.0, a=0.1), goal(1.0, a=0.2)], "point 1"),
        ([goal(math.nan, a=0.1)], "time_from_start must be finite"),
        ([goal(1.0, a=math.inf)], "position of 'a' must be finite"),
        ([goal(1.0, a=0.1), goal(2.0, b=0.2)], "point 1 names"),
        ([TrajectoryPoint({"a": 0.1}, 1.0, {"b": 0.0})], "velocity for 'b' but no position"),
        ([TrajectoryPoint({"a": 0.1}, 1.0, {"a": math.nan})], "velocity of 'a'"),
    ],
)
def test_bad_goals_are_refused_and_change_nothing(
    points: list[TrajectoryPoint], message: str
) -> None:
    ti = interp()
    ti.set_goal([goal(2.0, a=1.0)], 0.0)
    before = [ti.sample(t / 10) for t in range(30)]
    with pytest.raises(ValueError, match=message):
        ti.set_goal(points, 0.5)
    assert [ti.sample(t / 10) for t in range(30)] == before


def test_offsets_too_close_to_resolve_at_now_are_refused() -> None:
    ti = interp()
    with pytest.raises(ValueError, match="point 1"):
        ti.set_goal([goal(1.0, a=0.1), goal(1.0 + 1e-12, a=0.2)], 1e9)
    ti.set_goal([goal(1.0, a=0.1), goal(1.0 + 1e-12, a=0.2)], 0.0)  # resolvable near 0


def test_bad_seeds_and_settings_are_refused() -> None:
    ti = JointTrajectoryInterpolator(["a"])
    with pytest.raises(ValueError, match="unknown joint 'x'"):
        ti.seed({"a": 0.0, "x": 0.0})
    assert ti.sample(0.0) == {}  # nothing was seeded
    with pytest.raises(ValueError, match="seed position of 'a'"):
        ti.seed({"a": math.nan})
    with pytest.raises(ValueError, match="duplicate"):
        JointTrajectoryInterpolator(["a", "a"])
    with pytest.raises(ValueError, match="stall_lag"):
        JointTrajectoryInterpolator(["a"], stall_lag=0.0)
