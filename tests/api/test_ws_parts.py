"""The WebSocket's pure parts: token bucket, outbox (newest state wins), broadcaster, frames."""

from __future__ import annotations

import json

import pytest
from pydantic import BaseModel

from lupin.api import frames as f
from lupin.api.bodies import validate_frame
from lupin.api.broadcast import Outbox, StateBroadcaster, state_frame
from lupin.api.errors import ApiError
from lupin.api.ratelimit import TokenBucket
from lupin.api.ws import frame_id_of


def test_token_bucket_burst_then_rate() -> None:
    bucket = TokenBucket(rate=50, burst=50, now=0.0)
    assert sum(bucket.take(0.0) for _ in range(80)) == 50
    assert not bucket.take(0.0)
    assert sum(bucket.take(0.1) for _ in range(10)) == 5  # 0.1 s refills 5
    assert sum(bucket.take(100.0) for _ in range(80)) == 50  # never more than the burst
    with pytest.raises(ValueError):
        TokenBucket(rate=0, burst=1, now=0.0)


async def test_outbox_keeps_only_the_newest_state_and_every_reply() -> None:
    box = Outbox(max_replies=3)
    for i in range(5):
        box.offer_state(f"s{i}")
    box.offer_reply("r1")
    box.offer_reply("r2")
    assert box.replaced == 4
    assert await box.take() == ["r1", "r2", "s4"]  # replies first, then the newest state
    assert box.room.is_set()
    for i in range(3):
        box.offer_reply(f"r{i}")
    assert not box.room.is_set()  # the reader now waits before reading more
    assert await box.take() == ["r0", "r1", "r2"] and box.room.is_set()


class _State(BaseModel):
    t: float
    x: list[int]


def test_state_frame_splices_the_type_in() -> None:
    assert json.loads(state_frame(_State(t=1.5, x=[1]))) == {"type": "state", "t": 1.5, "x": [1]}


def test_broadcaster_serialises_once_and_never_blocks() -> None:
    calls = []

    def snapshot() -> _State:
        calls.append(1)
        return _State(t=float(len(calls)), x=[])

    b = StateBroadcaster(snapshot, hz=20)
    b.publish()
    assert calls == []  # no clients, no work
    boxes = [Outbox() for _ in range(50)]
    b.outboxes.update(boxes)
    for _ in range(10):
        b.publish()  # nobody takes anything: a stalled client in every box
    assert len(calls) == 10
    assert all(box.replaced == 9 and json.loads(box.state or "")["t"] == 10.0 for box in boxes)
    assert len({id(box.state) for box in boxes}) == 1  # the very same string for all


def test_broadcaster_survives_a_failing_snapshot(caplog: pytest.LogCaptureFixture) -> None:
    def boom() -> _State:
        raise RuntimeError("no state")

    b = StateBroadcaster(boom, hz=20)
    b.outboxes.add(Outbox())
    for _ in range(5):
        b.publish()
    assert len([r for r in caplog.records if "state frame" in r.getMessage()]) == 1
    caplog.clear()


def test_frames_validate_like_their_http_twins() -> None:
    frame = validate_frame(
        f.CLIENT_FRAME, {"type": "joint", "joint": "elbow_flex", "angle_deg": 3, "id": 7}
    )
    assert isinstance(frame, f.JointFrame) and frame.angle_deg == 3.0 and frame.id == 7
    with pytest.raises(ApiError) as err:
        validate_frame(f.CLIENT_FRAME, {"type": "joint", "joint": "x", "angle_deg": "3"})
    assert err.value.message.startswith("angle_deg:")  # the tag is not in the location
    with pytest.raises(ApiError):
        validate_frame(f.CLIENT_FRAME, {"type": "estop", "engaged": True, "force": 1})
    with pytest.raises(ApiError):
        validate_frame(f.CLIENT_FRAME, {"type": "joint", "joint": "", "angle_deg": 1})


@pytest.mark.parametrize(
    ("data", "want"),
    [
        ({"id": 3}, 3),
        ({"id": "a"}, "a"),
        ({"id": True}, None),
        ({"id": -1}, None),
        ({"id": "x" * 65}, None),
        ([1], None),
        (None, None),
        ({"id": 1.5}, None),
    ],
)
def test_frame_id_of(data: object, want: object) -> None:
    assert frame_id_of(data) == want
