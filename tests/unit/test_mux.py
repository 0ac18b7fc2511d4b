"""The velocity muxes, driven by a fake clock (plain floats)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from lupin.mux import (
    ZERO_TWIST,
    LockSpec,
    MuxOutput,
    SourceSpec,
    Twist,
    VelocityMux,
)
from lupin.takeover_mux import TakeoverMux

# SPEC §4: joy 100 / 0.3 s, manual 50 / 0.5 s, auto 10 / 0.5 s, idle 1 / 1.0 s.
SOURCES = [
    SourceSpec("joy", 100, 0.3),
    SourceSpec("manual", 50, 0.5),
    SourceSpec("auto", 10, 0.5),
    SourceSpec("idle", 1, 1.0),
]
ESTOP = LockSpec(VelocityMux.estop_lock_name, 256, 0.0)
JOY, MANUAL, AUTO = Twist(0.5, 0.0, 0.1), Twist(0.2, 0.0, 0.0), Twist(0.1, 0.0, -0.2)


def mux(*locks: LockSpec) -> VelocityMux:
    return VelocityMux(SOURCES, [*locks, ESTOP])


# -- priority and timeouts -------------------------------------------------------


def test_nothing_submitted_outputs_nothing() -> None:
    out = mux().output(0.0)
    assert out == MuxOutput(None, None, None)
    assert not out.active


def test_highest_fresh_priority_wins() -> None:
    m = mux()
    m.submit("auto", AUTO, 0.0)
    assert m.output(0.0) == MuxOutput("auto", AUTO)
    m.submit("manual", MANUAL, 0.0)
    assert m.output(0.0) == MuxOutput("manual", MANUAL)
    m.submit("joy", JOY, 0.0)
    assert m.output(0.0) == MuxOutput("joy", JOY)
    m.submit("auto", AUTO, 0.1)  # a newer low-priority twist does not win
    assert m.output(0.1).source == "joy"


@pytest.mark.parametrize(("name", "timeout"), [(s.name, s.timeout) for s in SOURCES])
def test_each_timeout_is_inclusive_at_the_exact_boundary(name: str, timeout: float) -> None:
    m = mux()
    m.submit(name, JOY, 0.0)
    assert m.output(timeout).source == name  # age == timeout: still fresh (twist_mux `>`)
    assert m.output(math.nextafter(timeout, math.inf)) == MuxOutput(None, None)


def test_expired_source_hands_over_to_the_next_priority() -> None:
    m = mux()
    m.submit("auto", AUTO, 0.0)
    m.submit("manual", MANUAL, 0.0)
    m.submit("auto", AUTO, 0.4)
    assert m.output(0.5).source == "manual"
    assert m.output(0.6) == MuxOutput("auto", AUTO)
    assert m.output(0.95) == MuxOutput(None, None)


def test_timeout_zero_never_expires() -> None:
    m = VelocityMux([SourceSpec("forever", 5, 0.0), SourceSpec("auto", 10, 0.5)])
    m.submit("forever", MANUAL, 0.0)
    assert m.output(1e9) == MuxOutput("forever", MANUAL)


def test_zero_then_silence_hands_over() -> None:
    """Runbook: on release the pad sends one zero twist then falls silent; after joy's
    0.3 s timeout the lower-priority source gets the bus back."""
    m = mux()
    t = 0.0
    while t < 1.0:  # manual at 10 Hz, joy at 20 Hz while LB is held
        m.submit("manual", MANUAL, t)
        m.submit("joy", JOY, t)
        t = round(t + 0.05, 6)
    m.submit("joy", ZERO_TWIST, 1.0)  # LB released: exactly one zero
    for t in (1.05, 1.1, 1.15, 1.2, 1.25):
        m.submit("manual", MANUAL, t)
        assert m.output(t) == MuxOutput("joy", ZERO_TWIST)  # joy still holds the bus
    m.submit("manual", MANUAL, 1.3)
    assert m.output(1.31) == MuxOutput("manual", MANUAL)
    assert m.output(1.81) == MuxOutput(None, None)  # manual stops too: silence, no zero


def test_a_stream_of_zeros_starves_lower_priorities() -> None:
    """The counterfactual the dead-man exists to prevent: zeros keep joy fresh forever."""
    m = mux()
    for i in range(100):
        m.submit("joy", ZERO_TWIST, i * 0.05)
        m.submit("manual", MANUAL, i * 0.05)
        assert m.output(i * 0.05).source == "joy"


def test_equal_priority_goes_to_the_most_recent_then_declaration_order() -> None:
    m = VelocityMux([SourceSpec("a", 10, 0.5), SourceSpec("b", 10, 0.5)])
    m.submit("b", AUTO, 0.0)
    m.submit("a", MANUAL, 0.0)
    assert m.output(0.0) == MuxOutput("a", MANUAL)  # same time: declared first wins
    m.submit("b", AUTO, 0.1)
    assert m.output(0.1) == MuxOutput("b", AUTO)  # most recent wins
    m.submit("a", MANUAL, 0.2)
    assert m.output(0.2).source == "a"


# -- locks and the E-stop --------------------------------------------------------------


def test_lock_masks_sources_below_its_priority_only() -> None:
    m = mux(LockSpec("pause", 50, 0.0))
    for name in ("joy", "manual", "auto"):
        m.submit(name, Twist(1.0), 0.0)
    m.set_lock("pause", True, 0.0)
    assert m.output(0.0) == MuxOutput("joy", Twist(1.0), "pause")
    m2 = mux(LockSpec("pause", 50, 0.0))
    m2.set_lock("pause", True, 0.0)
    m2.submit("auto", AUTO, 0.0)
    assert m2.output(0.0) == MuxOutput(None, None, "pause")  # auto (10 < 50) masked
    m2.submit("manual", MANUAL, 0.0)
    assert m2.output(0.0) == MuxOutput("manual", MANUAL, "pause")  # equal priority passes


def test_lock_release_and_lock_timeout() -> None:
    m = mux(LockSpec("nav_pause", 60, 1.0))
    m.set_lock("nav_pause", True, 0.0)
    m.submit("manual", MANUAL, 0.9)
    assert m.output(1.0) == MuxOutput(None, None, "nav_pause")  # age 1.0: still engaged
    m.submit("manual", MANUAL, 1.05)
    assert m.output(1.05).locked_by is None  # lock stale: disengaged
    m.set_lock("nav_pause", True, 2.0)
    assert m.output(2.0).locked_by == "nav_pause"
    m.set_lock("nav_pause", False, 2.1)
    assert m.output(2.1).locked_by is None


def test_estop_masks_everything_and_is_distinguishable_from_idle() -> None:
    m = mux()
    m.set_lock("estop", True, 0.0)
    assert m.output(0.0) == MuxOutput(None, None, "estop")  # locked, nothing submitted
    for s in SOURCES:
        m.submit(s.name, JOY, 1.0)
    assert m.output(1.0) == MuxOutput(None, None, "estop")
    assert m.output(1e6).locked_by == "estop"  # timeout 0: never expires
    m.set_lock("estop", False, 1.1)
    assert m.output(1.1).locked_by is None


def test_releasing_the_estop_never_replays_a_twist_sent_under_it() -> None:
    m = mux()
    m.set_lock("estop", True, 0.0)
    m.submit("manual", MANUAL, 0.0)
    m.set_lock("estop", False, 0.1)
    assert m.output(0.1) == MuxOutput("manual", ZERO_TWIST)
    m.submit("manual", MANUAL, 0.2)
    assert m.output(0.2) == MuxOutput("manual", MANUAL)


def test_locked_by_names_the_highest_engaged_lock() -> None:
    m = mux(LockSpec("low", 20, 0.0), LockSpec("high", 60, 0.0))
    m.set_lock("low", True, 0.0)
    m.set_lock("high", True, 0.0)
    assert m.output(0.0).locked_by == "high"
    m.set_lock("estop", True, 0.0)
    assert m.output(0.0).locked_by == "estop"


# -- errors, status ------------------------------------------------------------------


def test_unknown_names_and_bad_values_are_refused() -> None:
    m = mux()
    with pytest.raises(KeyError, match="unknown mux source 'nav'"):
        m.submit("nav", JOY, 0.0)
    with pytest.raises(KeyError, match="unknown mux lock 'brake'"):
        m.set_lock("brake", True, 0.0)
    for bad in (Twist(math.nan), Twist(0, math.inf), Twist(0, 0, -math.inf)):
        with pytest.raises(ValueError, match="non-finite"):
            m.submit("manual", bad, 0.0)
    assert m.output(0.0) == MuxOutput(None, None)  # nothing was recorded
    with pytest.raises(ValueError, match="duplicate"):
        VelocityMux([SourceSpec("a", 1, 0.5)], [LockSpec("a", 2, 0.0)])
    with pytest.raises(ValueError, match="timeout"):
        SourceSpec("a", 1, -0.1)
    with pytest.raises(ValueError, match="at least one source"):
        VelocityMux([])


def test_status_reports_freshness_masking_and_locks() -> None:
    m = mux(LockSpec("pause", 60, 0.0))
    m.submit("joy", JOY, 0.0)
    m.submit("manual", MANUAL, 0.4)
    m.set_lock("pause", True, 0.4)
    st_ = m.status(0.5)
    assert st_.active is None and st_.locked_by == "pause"
    assert st_.sources["joy"].age == pytest.approx(0.5) and not st_.sources["joy"].fresh
    assert st_.sources["manual"].fresh and st_.sources["manual"].masked
    assert st_.sources["auto"].age is None and not st_.sources["auto"].fresh
    assert st_.locks["pause"].engaged and st_.locks["pause"].value is True
    assert not st_.locks["estop"].engaged and st_.locks["estop"].value is None
    assert st_.to_dict()["locked_by"] == "pause"
    assert m.last_seen("manual") == 0.4 and m.last_seen("auto") == -math.inf


@given(
    st.lists(
        st.tuples(st.sampled_from([s.name for s in SOURCES]), st.floats(0.0, 3.0)),
        max_size=30,
    ),
    st.floats(0.0, 4.0),
)
def test_winner_matches_a_reference_model(subs: list[tuple[str, float]], now: float) -> None:
    m, last = mux(), {}
    for i, (name, t) in enumerate(sorted(subs, key=lambda s: s[1])):
        m.submit(name, Twist(float(i)), t)
        last[name] = (Twist(float(i)), t)
    spec = {s.name: s for s in SOURCES}
    fresh = [n for n, (_, t) in last.items() if now - t <= spec[n].timeout]
    out = m.output(now)
    if not fresh:
        assert out == MuxOutput(None, None)
    else:  # SOURCES' priorities are distinct
        best = max(fresh, key=lambda n: spec[n].priority)
        assert out == MuxOutput(best, last[best][0])


# -- the 2-source takeover mux ------------------------------------------------------------

TAKEOVER = [SourceSpec("manual", 50, 0.5), SourceSpec("auto", 10, 0.5)]


def test_takeover_manual_passes_and_auto_is_dropped_inside_the_window() -> None:
    m = TakeoverMux(TAKEOVER, manual_takeover_seconds=0.5)
    m.submit("auto", AUTO, 0.0)
    assert m.output(0.0) == MuxOutput("auto", AUTO)
    m.submit("manual", MANUAL, 0.1)  # manual passes straight through
    assert m.output(0.1) == MuxOutput("manual", MANUAL)
    m.submit("auto", AUTO, 0.35)
    m.submit("auto", AUTO, 0.5)
    assert m.output(0.5) == MuxOutput("manual", MANUAL)
    assert m.dropped == 2
    m.submit("auto", AUTO, 0.625)  # 0.525 s after manual: the window is over
    assert m.output(0.625) == MuxOutput("auto", AUTO)
    assert m.last_seen("auto") == 0.625


def test_takeover_window_boundary_is_inclusive() -> None:
    m = TakeoverMux(TAKEOVER, manual_takeover_seconds=0.5)
    m.submit("manual", MANUAL, 0.0)
    m.submit("auto", AUTO, 0.5)
    assert m.dropped == 1
    m.submit("auto", AUTO, math.nextafter(0.5, 1.0))
    assert m.output(0.6) == MuxOutput("auto", AUTO)


def test_takeover_goes_silent_when_stale_and_never_replays_older_twists() -> None:
    m = TakeoverMux(
        [SourceSpec("manual", 50, 5.0), SourceSpec("auto", 10, 0.5)],
        manual_takeover_seconds=0.5,
    )
    assert m.output(0.0) == MuxOutput(None, None)
    m.submit("manual", MANUAL, 0.0)
    m.submit("auto", AUTO, 1.0)
    assert m.output(1.5) == MuxOutput("auto", AUTO)
    assert m.output(1.6) == MuxOutput(None, None)  # manual is fresh but older: not replayed
    s = m.status(1.2)
    assert s.active == "auto" and s.locked_by is None and s.locks == {}
    assert s.sources["manual"].fresh and not s.sources["auto"].masked


def test_takeover_status_marks_auto_masked_during_takeover() -> None:
    m = TakeoverMux(TAKEOVER)
    m.submit("auto", AUTO, 0.0)
    m.submit("manual", MANUAL, 0.1)
    s = m.status(0.2)
    assert s.active == "manual" and s.sources["auto"].masked


def test_takeover_refuses_other_sources_and_bad_input() -> None:
    with pytest.raises(ValueError, match="exactly the sources"):
        TakeoverMux([*TAKEOVER, SourceSpec("joy", 100, 0.3)])
    with pytest.raises(ValueError, match="exactly the sources"):
        TakeoverMux(TAKEOVER[:1])
    m = TakeoverMux(TAKEOVER)
    with pytest.raises(KeyError, match="joy"):
        m.submit("joy", JOY, 0.0)
    with pytest.raises(ValueError, match="non-finite"):
        m.submit("manual", Twist(math.nan), 0.0)
