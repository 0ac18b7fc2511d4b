"""The dead-man base teleop, with a fake clock: the runbook's truth table."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lupin.mux import ZERO_TWIST, Twist
from lupin.pad import PadFrame
from lupin.pad_mapping import PadMapping, load_mapping
from lupin.teleop import BaseTeleop, Publish

# Each transport's raw encoding of one physical gesture, from the runbook: Bluetooth
# reports stick-forward/left as +1 (LB 6, RB 7, right X axis 2, triggers rest +1);
# xpad on USB reports them as -1 (LB 4, RB 5, right X axis 3, triggers rest -1).
TRANSPORT = {
    "xbox-bluetooth": {"lb": 6, "rb": 7, "yaw": 2, "sign": 1.0, "buttons": 15, "trig": 1.0},
    "xbox-usb": {"lb": 4, "rb": 5, "yaw": 3, "sign": -1.0, "buttons": 11, "trig": -1.0},
}


def pad(
    layout: str = "xbox-bluetooth",
    *,
    lb: bool = False,
    rb: bool = False,
    fwd: float = 0.0,
    left: float = 0.0,
    turn_left: float = 0.0,
    t: float = 0.0,
) -> PadFrame:
    """A frame for a physical gesture: stick pushed forward/left, right stick left."""
    tr = TRANSPORT[layout]
    s = float(tr["sign"])
    axes = [0.0] * 8
    axes[0], axes[1], axes[int(tr["yaw"])] = s * left, s * fwd, s * turn_left
    trig_axes = (4, 5) if layout == "xbox-bluetooth" else (2, 5)
    for a in trig_axes:
        axes[a] = float(tr["trig"])
    buttons = [0] * int(tr["buttons"])
    buttons[int(tr["lb"])] = int(lb)
    buttons[int(tr["rb"])] = int(rb)
    return PadFrame(t, tuple(axes), tuple(buttons))


@pytest.fixture()
def bt() -> BaseTeleop:
    return armed(BaseTeleop(load_mapping("xbox-bluetooth")))


def armed(teleop: BaseTeleop, layout: str = "xbox-bluetooth") -> BaseTeleop:
    """Start-up counts as after a vanish: show it one released frame first."""
    assert teleop.update(pad(layout), 0.0) is None
    return teleop


def press(teleop: BaseTeleop, now: float, layout: str = "xbox-bluetooth") -> None:
    """LB down with the sticks neutral (a stick already deflected at the press is blocked)."""
    assert teleop.update(pad(layout, lb=True), now) == Publish(teleop.source, ZERO_TWIST)


def test_no_motion_without_the_deadman(bt: BaseTeleop) -> None:
    assert bt.update(pad(fwd=1.0), 0.1) is None
    assert bt.tick(0.5) is None
    assert bt.next_due() is None


def test_drive_with_lb_feeds_joy(bt: BaseTeleop) -> None:
    press(bt, 0.05)
    out = bt.update(pad(lb=True, fwd=1.0), 0.1)
    assert out == Publish("joy", Twist(0.2, 0.0, 0.0))
    out = bt.update(pad(lb=True, left=1.0, turn_left=1.0), 0.12)
    assert out == Publish("joy", Twist(0.0, 0.2, 0.7))


def test_release_sends_exactly_one_zero_then_silence(bt: BaseTeleop) -> None:
    press(bt, 0.05)
    bt.update(pad(lb=True, fwd=1.0), 0.1)
    assert bt.update(pad(fwd=1.0), 0.2) == Publish("joy", ZERO_TWIST)
    # Silence, not a stream of zeros: more frames and every autorepeat tick publish nothing.
    assert bt.update(pad(fwd=1.0), 0.25) is None
    assert bt.update(pad(), 0.3) is None
    assert all(bt.tick(0.2 + i * 0.01) is None for i in range(300))
    assert bt.next_due() is None


def test_autorepeat_at_20hz_while_held_and_silence_after() -> None:
    bt = armed(BaseTeleop(load_mapping("xbox-bluetooth")))
    press(bt, -0.01)
    published = [0.0] if bt.update(pad(lb=True, fwd=0.5), 0.0) else []
    now = 0.0
    while now < 1.0 - 1e-9:  # no new frames: a perfectly steady hold
        now = round(now + 0.001, 3)
        out = bt.tick(now)
        if out is not None:
            assert out.twist.linear_x == pytest.approx(0.2 * (0.5 - 0.15) / 0.85)
            published.append(now)
    gaps = [b - a for a, b in itertools.pairwise(published)]
    assert len(published) == 21  # t = 0, 0.05, ..., 1.0
    assert max(gaps) == pytest.approx(0.05, abs=1e-6)  # never near the 0.3 s joy timeout
    assert bt.update(pad(), 1.01) == Publish("joy", ZERO_TWIST)
    assert all(bt.tick(1.01 + i * 0.01) is None for i in range(100))


def test_turbo_needs_the_deadman(bt: BaseTeleop) -> None:
    assert bt.update(pad(rb=True, fwd=1.0), 0.1) is None
    press(bt, 0.15)
    out = bt.update(pad(lb=True, rb=True, fwd=1.0, left=1.0, turn_left=1.0), 0.2)
    assert out == Publish("joy", Twist(0.6, 0.6, 1.4))


def test_deflected_stick_at_press_gives_no_motion_until_neutral(bt: BaseTeleop) -> None:
    assert bt.update(pad(fwd=1.0), 0.1) is None
    # The press takes over the bus (zeros at priority 100) but must not lurch the base.
    assert bt.update(pad(lb=True, fwd=1.0), 0.2) == Publish("joy", ZERO_TWIST)
    assert bt.tick(0.25) == Publish("joy", ZERO_TWIST)
    # The other stick was neutral at the press, so yaw works at once.
    assert bt.update(pad(lb=True, fwd=1.0, turn_left=1.0), 0.3) == Publish(
        "joy", Twist(0.0, 0.0, 0.7)
    )
    assert bt.update(pad(lb=True, fwd=0.05), 0.4) == Publish("joy", ZERO_TWIST)  # in deadzone
    assert bt.update(pad(lb=True, fwd=1.0), 0.5) == Publish("joy", Twist(0.2, 0.0, 0.0))


def test_unplug_mid_drive_is_one_zero_then_silence_and_no_resume(bt: BaseTeleop) -> None:
    press(bt, 0.05)
    bt.update(pad(lb=True, fwd=1.0), 0.1)
    assert bt.update(None, 0.2) == Publish("joy", ZERO_TWIST)
    assert bt.update(None, 0.25) is None
    assert all(bt.tick(0.2 + i * 0.01) is None for i in range(100))
    # The pad comes back with LB and the stick still held: nothing moves.
    assert bt.update(pad(lb=True, fwd=1.0), 1.5) is None
    assert bt.tick(1.6) is None
    assert bt.update(pad(fwd=1.0), 1.7) is None  # release: nothing was engaged, no zero
    # A fresh press with the stick still deflected: held, but no motion until neutral.
    assert bt.update(pad(lb=True, fwd=1.0), 1.8) == Publish("joy", ZERO_TWIST)
    assert bt.update(pad(lb=True), 1.9) == Publish("joy", ZERO_TWIST)
    assert bt.update(pad(lb=True, fwd=1.0), 2.0) == Publish("joy", Twist(0.2, 0.0, 0.0))


def test_held_at_start_up_needs_a_fresh_press() -> None:
    teleop = BaseTeleop(load_mapping("xbox-bluetooth"))
    assert teleop.update(pad(lb=True), 0.0) is None
    assert teleop.update(pad(), 0.1) is None
    assert teleop.update(pad(lb=True), 0.2) == Publish("joy", ZERO_TWIST)


def test_deadzone_is_rescaled_not_clipped(bt: BaseTeleop) -> None:
    press(bt, 0.05)
    assert bt.update(pad(lb=True, fwd=0.14), 0.1) == Publish("joy", ZERO_TWIST)
    out = bt.update(pad(lb=True, fwd=0.575), 0.2)  # (0.575 - 0.15) / 0.85 = 0.5
    assert out is not None
    assert out.twist.linear_x == pytest.approx(0.1)
    out = bt.update(pad(lb=True, fwd=1.0), 0.3)
    assert out is not None
    assert out.twist.linear_x == pytest.approx(0.2)  # full deflection still reaches full scale


@pytest.mark.parametrize("gesture", [{"fwd": 1.0}, {"left": -0.7}, {"turn_left": 0.4}])
@pytest.mark.parametrize("rb", [False, True])
def test_usb_and_bluetooth_give_the_same_physical_result(
    gesture: dict[str, float], rb: bool
) -> None:
    twists = []
    for layout in ("xbox-usb", "xbox-bluetooth"):
        teleop = armed(BaseTeleop(load_mapping(layout)), layout)
        press(teleop, 0.05, layout)
        out = teleop.update(pad(layout, lb=True, rb=rb, **gesture), 0.1)
        assert out is not None and out.source == "joy"
        twists.append(out.twist)
    usb, blue = twists
    # Same direction on both; magnitudes differ only by the per-transport deadzone.
    for a, b in ((usb.linear_x, blue.linear_x), (usb.linear_y, blue.linear_y)):
        assert math.copysign(1, a) == math.copysign(1, b) or a == b == 0
    assert usb.angular_z * blue.angular_z >= 0
    assert (usb.linear_x > 0) == (gesture.get("fwd", 0) > 0)
    assert (usb.linear_y < 0) == (gesture.get("left", 0) < 0)
    assert (usb.angular_z > 0) == (gesture.get("turn_left", 0) > 0)
    if all(abs(v) == 1.0 for v in gesture.values()):
        assert usb == blue  # full deflection: the deadzones drop out, exactly equal


def test_usb_deadman_is_button_4_not_6() -> None:
    usb = armed(BaseTeleop(load_mapping("xbox-usb")), "xbox-usb")
    frame = pad("xbox-usb", fwd=1.0)
    six = PadFrame(0.1, frame.axes, tuple(1 if i == 6 else b for i, b in enumerate(frame.buttons)))
    assert usb.update(six, 0.1) is None  # button 6 is Back on xpad, not the dead-man
    press(usb, 0.15, "xbox-usb")
    assert usb.update(pad("xbox-usb", lb=True, fwd=1.0), 0.2) == Publish("joy", Twist(0.2, 0, 0))


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 1.5, -1.01])
def test_bad_axes_read_neutral_and_are_counted(bt: BaseTeleop, bad: float) -> None:
    press(bt, 0.05)
    frame = pad(lb=True, turn_left=1.0)
    axes = list(frame.axes)
    axes[1] = bad
    out = bt.update(PadFrame(0.1, tuple(axes), frame.buttons), 0.1)
    assert out == Publish("joy", Twist(0.0, 0.0, 0.7))
    assert bt.bad_axes == 1


def test_a_short_frame_is_not_a_crash(bt: BaseTeleop) -> None:
    short = PadFrame(0.1, (0.0,), tuple([0] * 6 + [1]))
    assert bt.update(short, 0.1) == Publish("joy", ZERO_TWIST)
    assert bt.bad_axes == 2  # axis 1 and axis 2 are missing


# -- DS4: no dead-man, feeds manual --------------------------------------------------------


def ds4(fwd: float = 0.0, turn_left: float = 0.0) -> PadFrame:
    axes = [0.0, -fwd, -1.0, -turn_left, 0.0, -1.0, 0.0, 0.0]  # hid-sony: up/left read -1
    return PadFrame(0.0, tuple(axes), (0,) * 13)


def test_ds4_drives_manual_while_deflected_then_one_zero() -> None:
    teleop = BaseTeleop(load_mapping("ds4"))
    assert teleop.update(ds4(), 0.0) is None
    assert teleop.update(ds4(fwd=1.0), 0.1) == Publish("manual", Twist(0.2, 0.0, 0.0))
    assert teleop.tick(0.15) == Publish("manual", Twist(0.2, 0.0, 0.0))  # autorepeat
    assert teleop.update(ds4(), 0.2) == Publish("manual", ZERO_TWIST)
    assert teleop.update(ds4(), 0.3) is None
    assert all(teleop.tick(0.2 + i * 0.01) is None for i in range(100))


def test_ds4_vanish_while_deflected_waits_for_neutral() -> None:
    teleop = BaseTeleop(load_mapping("ds4"))
    teleop.update(ds4(), 0.0)
    teleop.update(ds4(turn_left=1.0), 0.1)
    assert teleop.update(None, 0.2) == Publish("manual", ZERO_TWIST)
    assert teleop.update(ds4(turn_left=1.0), 1.0) is None
    assert teleop.update(ds4(), 1.1) is None
    assert teleop.update(ds4(turn_left=1.0), 1.2) == Publish("manual", Twist(0.0, 0.0, 0.7))


def test_ds4_deflected_at_start_up_waits_for_neutral() -> None:
    teleop = BaseTeleop(load_mapping("ds4"))
    assert teleop.update(ds4(fwd=1.0), 0.0) is None
    assert teleop.update(ds4(), 0.1) is None
    assert teleop.update(ds4(fwd=1.0), 0.2) is not None


def test_mapping_without_deadman_cannot_feed_joy() -> None:
    data = load_mapping("ds4").model_dump()
    data["source"] = "joy"
    with pytest.raises(ValueError, match="must feed 'manual'"):
        PadMapping.model_validate(data)


# -- the invariant, over random operator behaviour --------------------------------------

events = st.lists(
    st.one_of(
        st.tuples(st.just("frame"), st.booleans(), st.sampled_from([0.0, 0.1, 0.6, 1.0, math.nan])),
        st.tuples(st.just("vanish"), st.just(False), st.just(0.0)),
        st.tuples(st.just("tick"), st.just(False), st.just(0.0)),
    ),
    max_size=60,
)


@settings(max_examples=300, deadline=None)
@given(events)
def test_silence_invariant(seq: list[tuple[str, bool, float]]) -> None:
    """Whatever the operator does: nothing is published while LB is up except exactly one
    zero right after the drive ends, and every twist is finite."""
    teleop = BaseTeleop(load_mapping("xbox-bluetooth"))
    now = 0.0
    held = False
    zero_sent = True
    for kind, lb, fwd in seq:
        now += 0.03
        if kind == "frame":
            out = teleop.update(pad(lb=lb, fwd=fwd), now)
            held = lb
        elif kind == "vanish":
            out = teleop.update(None, now)
            held = False
        else:
            out = teleop.tick(now)
        if out is None:
            continue
        assert out.source == "joy" and out.twist.is_finite()
        if not held:
            assert out.twist == ZERO_TWIST and not zero_sent, "a second message after release"
            zero_sent = True
        else:
            zero_sent = False
