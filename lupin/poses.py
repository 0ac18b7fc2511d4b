"""Taught poses in ``$LUPIN_HOME/poses.yaml``, and how a move to one is planned.

A pose is radians about each joint's zero, so it means something for one
physical arm and its calibration only: per-robot state, not the package. Writes
are atomic (temp file + rename) and keep the previous file as ``.bak``.

Going to a pose streams setpoints at 20 Hz at a set speed rather than one jump,
and refuses a largest single-joint travel over ``max_travel`` (0.35 rad unless
raised): a stale pose or a bad limit must not become a large unexpected swing
(bring-up seed).
"""

from __future__ import annotations

import math
import os
import re
import shutil
import tempfile
from collections.abc import Iterable, Mapping
from pathlib import Path

import yaml

from lupin.config import ConfigError, read_yaml
from lupin.trajectory import TrajectoryPoint

NAME = re.compile(r"^[A-Za-z0-9_-]{1,40}$")
STREAM_HZ = 20.0


class PoseStore:
    def __init__(self, path: Path, joints: list[str]) -> None:
        self.path = path
        self.joints = joints

    def load(self) -> dict[str, dict[str, float]]:
        if not self.path.exists():
            return {}
        raw = read_yaml(self.path)
        poses = raw.get("poses", {})
        if not isinstance(poses, dict):
            raise ConfigError(f"{self.path}: poses: expected a mapping of pose names")
        out: dict[str, dict[str, float]] = {}
        for name, pose in poses.items():
            if not isinstance(pose, dict):
                raise ConfigError(f"{self.path}: poses.{name}: expected joint: radians")
            clean = {}
            for joint, value in pose.items():
                if joint not in self.joints:
                    raise ConfigError(f"{self.path}: poses.{name}.{joint}: not an arm joint")
                if not isinstance(value, int | float) or not math.isfinite(value):
                    raise ConfigError(f"{self.path}: poses.{name}.{joint}: not a finite number")
                clean[joint] = float(value)
            out[str(name)] = clean
        return out

    def save_all(self, poses: Mapping[str, Mapping[str, float]]) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.path.exists():
            shutil.copy2(self.path, self.path.with_name(self.path.name + ".bak"))
        text = yaml.safe_dump(
            {"poses": {n: {j: round(v, 6) for j, v in p.items()} for n, p in poses.items()}},
            sort_keys=True,
        )
        fd, tmp = tempfile.mkstemp(dir=self.path.parent, prefix=".poses-", suffix=".yaml")
        try:
            with os.fdopen(fd, "w") as f:
                f.write(text)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    def put(self, name: str, pose: Mapping[str, float]) -> None:
        if not NAME.match(name):
            raise ValueError(f"bad pose name {name!r}: use letters, digits, _ and -")
        poses = self.load()
        poses[name] = dict(pose)
        self.save_all(poses)

    def delete(self, name: str) -> bool:
        poses = self.load()
        if name not in poses:
            return False
        del poses[name]
        self.save_all(poses)
        return True

    def limits(self) -> dict[str, tuple[float, float]]:
        """The envelope spanned by the taught poses, per joint: for narrowing, not calibrating."""
        return envelope(self.load().values())


def envelope(poses: Iterable[Mapping[str, float]]) -> dict[str, tuple[float, float]]:
    """Per joint, the (min, max) radians over ``poses``; a joint no pose names is absent.

    Shared by :meth:`PoseStore.limits` and ``lupin pose limits`` (which gets the
    poses over the API), so the two cannot disagree.
    """
    out: dict[str, tuple[float, float]] = {}
    for pose in poses:
        for joint, v in pose.items():
            lo, hi = out.get(joint, (v, v))
            out[joint] = (min(lo, v), max(hi, v))
    return out


def largest_travel(start: Mapping[str, float], goal: Mapping[str, float]) -> float:
    return max((abs(goal[j] - start[j]) for j in goal if j in start), default=0.0)


def stream_points(
    start: Mapping[str, float], goal: Mapping[str, float], speed: float
) -> list[TrajectoryPoint]:
    """Setpoints at 20 Hz along the straight joint-space line, the largest joint at ``speed``."""
    travel = largest_travel(start, goal)
    duration = max(travel / speed, 1.0 / STREAM_HZ)
    steps = max(1, math.ceil(duration * STREAM_HZ))
    points = []
    for k in range(1, steps + 1):
        f = k / steps
        points.append(
            TrajectoryPoint(
                positions={j: start[j] + (goal[j] - start[j]) * f for j in goal},
                time_from_start=duration * f,
            )
        )
    return points
