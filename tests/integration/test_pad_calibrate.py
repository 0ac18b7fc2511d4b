"""``lupin pad-calibrate`` end to end in a pseudo-terminal, driven by a scripted pad.

The replay file plays a Bluetooth pad whose indices and signs all differ from the
packaged defaults, so every value in the written file must have been captured.
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import subprocess
import sys
import time
from pathlib import Path

import yaml

from lupin.pad_mapping import load_mapping

N_AXES, N_BUTTONS = 8, 15
REST_AXES = {5: -1.0, 2: -1.0}  # this pad's triggers rest at -1


class Pty:
    """A child process on a pseudo-terminal: read its prompts, type answers."""

    def __init__(self, argv: list[str], env: dict[str, str]) -> None:
        master, slave = os.openpty()
        self.proc = subprocess.Popen(
            argv, stdin=slave, stdout=slave, stderr=slave, env=env, close_fds=True
        )
        os.close(slave)
        self.master = master
        self.seen = b""

    def _read(self, deadline: float) -> bytes:
        ready, _, _ = select.select([self.master], [], [], max(0.0, deadline - time.monotonic()))
        if not ready:
            return b""
        try:
            return os.read(self.master, 4096)
        except OSError:  # EIO: the child closed the terminal
            return b""

    def expect(self, needle: str, timeout: float = 20.0) -> None:
        deadline = time.monotonic() + timeout
        while needle.encode() not in self.seen:
            chunk = self._read(deadline)
            if not chunk:
                raise AssertionError(f"no {needle!r} in the output:\n{self.text}")
            self.seen += chunk
        # Keep only what follows, so the next expect waits for a new prompt.
        self.done = self.seen[: self.seen.index(needle.encode()) + len(needle)]
        self.seen = self.seen[len(self.done) :]

    def type(self, text: str) -> None:
        os.write(self.master, text.encode())

    def finish(self, timeout: float = 20.0) -> int:
        deadline = time.monotonic() + timeout
        while chunk := self._read(deadline):
            self.seen += chunk
        return self.proc.wait(max(0.1, deadline - time.monotonic()))

    def __enter__(self) -> Pty:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(10)
        with contextlib.suppress(OSError):
            os.close(self.master)

    @property
    def text(self) -> str:
        return self.seen.decode(errors="replace")


def frame(t: float, axes: dict[int, float] | None = None, buttons: tuple[int, ...] = ()) -> str:
    values = [REST_AXES.get(i, 0.0) for i in range(N_AXES)]
    for i, v in (axes or {}).items():
        values[i] = v
    pressed = [1 if i in buttons else 0 for i in range(N_BUTTONS)]
    return json.dumps({"t": round(t, 3), "axes": values, "buttons": pressed})


# The gestures in prompt order, as this (odd) pad reports them.
GESTURES: list[tuple[dict[int, float], tuple[int, ...]]] = [
    ({}, (8,)),  # LB: dead-man
    ({}, (9,)),  # RB: turbo
    ({1: -1.0}, ()),  # left stick forward reads -1 here
    ({0: -0.9}, ()),  # left stick left reads -0.9
    ({3: 1.0}, ()),  # right stick left reads +1
    ({}, (2,)),  # B
    ({}, (1,)),  # X
    ({}, (4,)),  # Y
    ({}, (0,)),  # A
    ({7: -1.0}, ()),  # D-pad up
    ({6: -1.0}, ()),  # D-pad left
    ({}, (11,)),  # Menu
    ({}, (10,)),  # View
    ({5: 0.5}, ()),  # RT on its way...
]


def script(path: Path, gestures: list[tuple[dict[int, float], tuple[int, ...]]]) -> Path:
    lines = [frame(0.0)]
    t = 1.5  # leaves time to answer the "press Enter" prompt first
    for axes, buttons in gestures:
        lines.append(frame(t, axes, buttons))
        t += 0.05
        lines.append(frame(t))
        t += 0.05
    path.write_text("\n".join(lines) + "\n")
    return path


def spawn(home: Path, replay: Path) -> Pty:
    env = {**os.environ, "LUPIN_HOME": str(home), "NO_COLOR": "1"}
    argv = [sys.executable, "-m", "lupin", "pad-calibrate", "--pad", f"replay:{replay}"]
    return Pty([*argv, "--pad-layout", "xbox-bluetooth"], env)


def test_calibrator_captures_indices_and_signs_and_rewrites_only_its_file(
    tmp_path: Path,
) -> None:
    home = tmp_path / "home"
    pads = home / "pads"
    pads.mkdir(parents=True)
    old = load_mapping("xbox-bluetooth").model_dump(mode="json", exclude_none=True)
    old["deadzone"] = 0.2  # a hand-tuned value the calibrator must keep
    (pads / "xbox-bluetooth.yaml").write_text(yaml.safe_dump(old))
    usb = pads / "xbox-usb.yaml"
    usb.write_text("# the other transport's file: not to be touched\n")
    pull = [({5: 1.0}, ()), ({2: 0.96}, ())]  # RT to full (+1), LT to 0.96
    replay = script(tmp_path / "pad.jsonl", GESTURES[:-1] + pull)

    with spawn(home, replay) as pty:
        pty.expect("press Enter")
        pty.type("\n")
        pty.expect("Press LB (the dead-man)")
        pty.expect("-> button 8")
        pty.expect("Push the LEFT stick FORWARD")
        pty.expect("-> axis 1 (-)")
        pty.expect("Pull LT (gripper close)")
        pty.expect("[y/N]")
        pty.type("y\n")
        assert pty.finish() == 0, pty.text

    written = yaml.safe_load((pads / "xbox-bluetooth.yaml").read_text())
    assert yaml.safe_load((pads / "xbox-bluetooth.yaml.bak").read_text()) == old
    assert usb.read_text() == "# the other transport's file: not to be touched\n"
    assert not (pads / "xbox-usb.yaml.bak").exists()
    assert (written["enable_button"], written["shoulder_disable_button"]) == (8, 8)
    assert written["enable_turbo_button"] == 9
    assert written["axis_linear"] == {"x": 1, "y": 0} and written["axis_angular"] == {"yaw": 3}
    # Forward and left read negative on this pad: the scales' signs flip to match.
    assert written["scale_linear"] == {"x": -0.2, "y": -0.2}
    assert written["scale_linear_turbo"] == {"x": -0.6, "y": -0.6}
    assert written["scale_angular"] == {"yaw": 0.7}
    assert written["scale_angular_turbo"] == {"yaw": 1.4}
    arm = written["arm_controls"]
    assert arm["shoulder_pan"] == {"plus_button": 2, "minus_button": 1}
    assert arm["shoulder_lift"] == {"plus_button": 4, "minus_button": 0}
    assert arm["elbow"] == {"axis": 7, "sign": -1} and arm["wrist"] == {"axis": 6, "sign": -1}
    assert arm["wrist_roll"] == {"plus_button": 11, "minus_button": 10}
    assert (written["gripper_open_axis"], written["gripper_open_rest"]) == (5, -1.0)
    assert (written["gripper_open_full"], written["gripper_open_enabled"]) == (1.0, True)
    assert (written["gripper_close_axis"], written["gripper_close_full"]) == (2, 0.96)
    assert written["deadzone"] == 0.2
    assert load_mapping("xbox-bluetooth", home=home).enable_button == 8  # it loads back


def test_calibrator_aborts_without_writing_when_the_pad_stops(tmp_path: Path) -> None:
    home = tmp_path / "home"
    replay = script(tmp_path / "short.jsonl", GESTURES[:3])
    with spawn(home, replay) as pty:
        pty.expect("press Enter")
        pty.type("\n")
        assert pty.finish() == 1
        assert "calibration aborted: the pad reader ended" in pty.text
    assert not (home / "pads").exists()


def test_declining_writes_nothing(tmp_path: Path) -> None:
    home = tmp_path / "home"
    full = [*GESTURES[:-1], ({5: 1.0}, ()), ({2: 1.0}, ())]
    with spawn(home, script(tmp_path / "pad.jsonl", full)) as pty:
        pty.expect("press Enter")
        pty.type("\n")
        pty.expect("[y/N]")
        pty.type("n\n")
        assert pty.finish() == 1
    assert not (home / "pads" / "xbox-bluetooth.yaml").exists()
