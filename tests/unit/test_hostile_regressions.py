"""Bugs the reliability suite's hostile-input tests found, pinned at the unit level.

Each test names the input that used to crash, hang or mislead, and what it gets now.
The end-to-end versions live in tests/reliability/test_hostile_*.py.
"""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from lupin import api_models as m
from lupin.api.openapi import build_document


def test_pose_go_speed_has_a_floor_so_the_stream_stays_bounded() -> None:
    # 1e-12 rad/s was accepted and asked stream_points for ~1e13 setpoints: a frozen loop.
    with pytest.raises(ValidationError, match="speed_rad_s"):
        m.PoseGoRequest(speed_rad_s=1e-12)
    assert m.PoseGoRequest(speed_rad_s=m.MIN_POSE_SPEED_RAD_S).speed_rad_s == 0.01


def test_a_pose_cannot_be_taught_empty() -> None:
    # {"joints_rad": {}} was stored; going to it named no joint and answered 500.
    with pytest.raises(ValidationError, match="joints_rad"):
        m.PoseSaveRequest(joints_rad={})
    assert m.PoseSaveRequest().joints_rad is None  # capture the measured pose
    assert m.PoseSaveRequest(joints_rad={"elbow_flex": 0.1}).joints_rad == {"elbow_flex": 0.1}


def test_the_document_links_a_taught_pose_to_what_takes_its_name() -> None:
    doc = build_document(None, token_required=False)
    links = doc["paths"]["/api/arm/poses/{pose}"]["put"]["responses"]["200"]["links"]
    assert {link["operationId"] for link in links.values()} == {
        "get_pose",
        "go_pose",
        "delete_pose",
    }
    assert all(link["parameters"] == {"pose": "$response.body#/name"} for link in links.values())
    ops = {op["operationId"] for path in doc["paths"].values() for op in path.values()}
    assert {link["operationId"] for link in links.values()} <= ops
