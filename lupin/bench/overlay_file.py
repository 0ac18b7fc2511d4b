"""``$LUPIN_HOME/arm.yaml``: this arm's measured zero/min/max, with the measurements beside them.

This file supplies the soft limits that stop the arm, so a new one is
validated twice before it lands — as an :class:`ArmOverlay`, and by loading
the whole profile with it — and then written through a temporary file. Each
joint keeps its measurement (swept range, samples, margin, the homing offset
written): the offset exists nowhere else, and is the only record if a servo is
swapped (bring-up seed).
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from lupin.bench.files import write_text_atomic
from lupin.bench.homing import JointCalibration
from lupin.config import ConfigError, format_validation_error, load_profile, read_yaml
from lupin.config_models import ArmOverlay, RobotProfile

OVERLAY_NAME = "arm.yaml"
HEADER = (
    "# This arm's measured calibration, overlaid on the packaged profile at load time.\n"
    "# Written by lupin calibrate; each value sits beside the measurement it came from.\n"
    "# Delete this file to fall back to the profile's conservative defaults.\n"
)


def build_overlay(
    path: Path, calibrations: Sequence[JointCalibration], *, stamp: str, source: str
) -> dict[str, Any]:
    """The existing overlay (if any) with ``calibrations`` replacing their joints."""
    existing = read_yaml(path) if path.exists() else {}
    joints = dict(existing.get("joints") or {})
    for cal in calibrations:
        joints[cal.name] = {
            "zero": cal.zero,
            "min": cal.min,
            "max": cal.max,
            "measurement": {**cal.measurement, "source": source, "when": stamp},
        }
    return {**existing, "joints": joints}


def validate_overlay(
    data: dict[str, Any], *, profile: str | None, config_file: str | None
) -> RobotProfile:
    """Refuse (ConfigError) an overlay the daemon would refuse, before it is written."""
    try:
        ArmOverlay.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error("new arm.yaml", exc, data)) from None
    with tempfile.TemporaryDirectory(prefix="lupin-overlay-") as tmp:
        (Path(tmp) / OVERLAY_NAME).write_text(render(data), encoding="utf-8")
        return load_profile(profile, config_file=config_file, home=Path(tmp))


def render(data: dict[str, Any]) -> str:
    return HEADER + yaml.safe_dump(data, sort_keys=False)


def save_overlay(path: Path, data: dict[str, Any]) -> None:
    write_text_atomic(path, render(data))
