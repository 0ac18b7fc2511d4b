"""``lupin pad-calibrate``: probe a pad interactively and rewrite its mapping file.

Runbook ("Xbox control layout"): detect the transport, open our own reader
(teleop is not driving: on evdev the device is grabbed, so a running daemon sees
nothing while buttons are probed), walk each control one at a time capturing
its index and direction, measure the trigger rest/full, and rewrite ONLY the
matching ``$LUPIN_HOME/pads/<layout>.yaml``, backing up the old one and leaving
the other transport's file alone. Calibrate once per transport.

Each step waits for the next distinct input (a button going down, or an axis
swinging away from its rest value and back), in order, so a scripted replay
drives it as well as a person does.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import yaml

from lupin import registry
from lupin.config import ConfigError, read_yaml
from lupin.pad import PadFrame, PadReader, open_pad
from lupin.pad_mapping import load_mapping, override_path, parse_mapping, resolve_layout

SWING_START, SWING_END = 0.5, 0.25  # away from rest to start a swing, back within to end it
STEP_TIMEOUT_S = 60.0
Kind = Literal["button", "stick", "dpad", "trigger"]


@dataclass(frozen=True)
class Press:
    button: int


@dataclass(frozen=True)
class Swing:
    axis: int
    sign: int  # the direction the axis moved away from rest
    rest: float
    extreme: float


class InputEdges:
    """Pure: frames -> distinct inputs relative to a rest frame."""

    def __init__(self, rest: PadFrame) -> None:
        self.rest = rest.axes
        self.down = {i for i, b in enumerate(rest.buttons) if b}
        self.swinging: dict[int, float] = {}

    def feed(self, frame: PadFrame) -> list[Press | Swing]:
        out: list[Press | Swing] = []
        for i, b in enumerate(frame.buttons):
            if b and i not in self.down:
                self.down.add(i)
                out.append(Press(i))
            elif not b:
                self.down.discard(i)
        for i, v in enumerate(frame.axes[: len(self.rest)]):
            rest = self.rest[i]
            if not (math.isfinite(v) and math.isfinite(rest)):
                continue
            if i in self.swinging:
                if abs(v - rest) > abs(self.swinging[i] - rest):
                    self.swinging[i] = v
                if abs(v - rest) < SWING_END:
                    extreme = self.swinging.pop(i)
                    out.append(Swing(i, 1 if extreme > rest else -1, rest, extreme))
            elif abs(v - rest) > SWING_START:
                self.swinging[i] = v
        return out


@dataclass(frozen=True)
class Step:
    key: str
    kind: Kind
    prompt: str
    opposite: str = ""  # a D-pad that reports buttons: the prompt for its minus direction


def _steps(n: dict[str, str]) -> tuple[Step, ...]:
    """The walk, in prompt order; a pad without a dead-man (DS4) skips that step."""
    deadman = n.get("deadman")
    first = [Step("enable_button", "button", f"Press {deadman} (the dead-man)")] if deadman else []
    return (*first,
        Step("enable_turbo_button", "button", f"Press {n['turbo']} (turbo)"),
        Step("linear_x", "stick", "Push the LEFT stick FORWARD, then let go"),
        Step("linear_y", "stick", "Push the LEFT stick LEFT, then let go"),
        Step("yaw", "stick", "Push the RIGHT stick LEFT, then let go"),
        Step("shoulder_pan+", "button", f"Press {n['pan+']} (shoulder pan +)"),
        Step("shoulder_pan-", "button", f"Press {n['pan-']} (shoulder pan -)"),
        Step("shoulder_lift+", "button", f"Press {n['lift+']} (shoulder lift +)"),
        Step("shoulder_lift-", "button", f"Press {n['lift-']} (shoulder lift -)"),
        Step("elbow", "dpad", "Press D-pad UP (elbow +)", "Press D-pad DOWN (elbow -)"),
        Step("wrist", "dpad", "Press D-pad LEFT (wrist +)", "Press D-pad RIGHT (wrist -)"),
        Step("wrist_roll+", "button", f"Press {n['roll+']} (wrist roll +)"),
        Step("wrist_roll-", "button", f"Press {n['roll-']} (wrist roll -)"),
        Step("gripper_open", "trigger", f"Pull {n['open']} (gripper open) all the way, let go"),
        Step("gripper_close", "trigger", f"Pull {n['close']} (gripper close) all the way, let go"),
    )  # fmt: skip


XBOX = {"deadman": "LB", "turbo": "RB", "pan+": "B", "pan-": "X", "lift+": "Y", "lift-": "A",
        "roll+": "Menu (Start)", "roll-": "View (Back)", "open": "RT", "close": "LT"}  # fmt: skip
DS4 = {"turbo": "R1", "pan+": "circle", "pan-": "square", "lift+": "triangle", "lift-": "cross",
       "roll+": "options", "roll-": "share", "open": "R2", "close": "L2"}  # fmt: skip
STEPS = {
    "xbox-usb": _steps(XBOX),
    "xbox-bluetooth": _steps(XBOX),
    "ds4": _steps(DS4),
}
Answer = Press | Swing | tuple[Press, Press]


class Aborted(Exception):
    pass


def apply_answers(data: dict[str, Any], answers: dict[str, Answer]) -> dict[str, Any]:
    """Fold the captured indices and directions into mapping data (a copy)."""
    out: dict[str, Any] = {**data, "arm_controls": dict(data.get("arm_controls", {}))}
    for key, ans in answers.items():
        if isinstance(ans, Press) and key in ("enable_button", "enable_turbo_button"):
            out[key] = ans.button
            if key == "enable_button":  # the shoulder gate follows the dead-man
                out["shoulder_disable_button"] = ans.button
        elif isinstance(ans, Swing) and key in ("linear_x", "linear_y", "yaw"):
            # The scale's sign encodes the axis polarity: pushing forward (or left)
            # must give a positive command whatever the transport reports.
            group, field = ("angular", "yaw") if key == "yaw" else ("linear", key[-1])
            out[f"axis_{group}"] = {**out[f"axis_{group}"], field: ans.axis}
            for scale in (f"scale_{group}", f"scale_{group}_turbo"):
                old = out[scale][field]
                out[scale] = {**out[scale], field: ans.sign * abs(old)}
        elif isinstance(ans, Swing) and key.startswith("gripper_"):
            side = key.removeprefix("gripper_")
            out[f"gripper_{side}_axis"] = ans.axis
            out[f"gripper_{side}_rest"] = round(ans.rest, 3)
            out[f"gripper_{side}_full"] = round(ans.extreme, 3)
            out[f"gripper_{side}_enabled"] = True
        elif isinstance(ans, Swing):
            out["arm_controls"][key] = {"axis": ans.axis, "sign": ans.sign}
        elif isinstance(ans, tuple):
            out["arm_controls"][key] = {"plus_button": ans[0].button, "minus_button": ans[1].button}
    for role in ("shoulder_pan", "shoulder_lift", "wrist_roll"):
        plus, minus = answers.get(f"{role}+"), answers.get(f"{role}-")
        if isinstance(plus, Press) and isinstance(minus, Press):
            out["arm_controls"][role] = {"plus_button": plus.button, "minus_button": minus.button}
    return out


class Session:
    """One calibration: a pump task turns frames into inputs, the steps consume them."""

    def __init__(self, reader: PadReader, timeout: float = STEP_TIMEOUT_S) -> None:
        self.reader = reader
        self.timeout = timeout
        self.latest: PadFrame | None = None
        self.edges: InputEdges | None = None
        self.inputs: asyncio.Queue[Press | Swing | None] = asyncio.Queue()
        self.first = asyncio.Event()
        self.taken: dict[tuple[str, int], str] = {}

    async def pump(self) -> None:
        try:
            async for item in self.reader.frames():
                if item is None:
                    say("(the pad disconnected; waiting for it to come back)")
                    continue
                self.latest = item
                self.first.set()
                for event in self.edges.feed(item) if self.edges else []:
                    self.inputs.put_nowait(event)
        finally:
            self.inputs.put_nowait(None)  # the reader ended
            self.first.set()

    async def run(self, steps: tuple[Step, ...]) -> dict[str, Answer]:
        await asyncio.wait_for(self.first.wait(), self.timeout)
        if self.latest is None:
            raise Aborted("the pad reader ended before any frame")
        await ask("Leave every control at rest, then press Enter: ")
        assert self.latest is not None
        self.edges = InputEdges(self.latest)
        answers: dict[str, Answer] = {}
        for step in steps:
            say(step.prompt)
            got = await self.next_input(step, step.kind)
            if isinstance(got, Press) and step.kind == "dpad":
                say(step.opposite)
                other = await self.next_input(step, "button")
                assert isinstance(other, Press)
                answers[step.key] = (got, other)
            else:
                answers[step.key] = got
            say(f"  -> {_describe(answers[step.key])}")
        return answers

    async def next_input(self, step: Step, kind: Kind) -> Press | Swing:
        want = {"button": (Press,), "dpad": (Press, Swing)}.get(kind, (Swing,))
        while True:
            try:
                event = await asyncio.wait_for(self.inputs.get(), self.timeout)
            except TimeoutError:
                raise Aborted(f"no input for {self.timeout:g} s at: {step.prompt}") from None
            if event is None:
                raise Aborted("the pad reader ended before calibration finished")
            if not isinstance(event, want):
                continue  # e.g. a stick brushed while pressing a button
            slot = ("button", event.button) if isinstance(event, Press) else ("axis", event.axis)
            if slot in self.taken:
                say(f"  {slot[0]} {slot[1]} is already {self.taken[slot]}; {step.prompt}")
                continue
            self.taken[slot] = step.key
            return event


def _describe(ans: Answer) -> str:
    if isinstance(ans, Press):
        return f"button {ans.button}"
    if isinstance(ans, Swing):
        return f"axis {ans.axis} ({'+' if ans.sign > 0 else '-'}), rest {ans.rest:.2f}"
    return f"buttons {ans[0].button} / {ans[1].button}"


def say(text: str) -> None:
    print(text, flush=True)


def _wake(ready: asyncio.Future[None]) -> None:
    if not ready.done():
        ready.set_result(None)


async def ask(prompt: str) -> str:
    """Read one line without a thread, so Ctrl-C never waits on a blocked reader thread."""
    print(prompt, end="", flush=True)
    loop = asyncio.get_running_loop()
    ready: asyncio.Future[None] = loop.create_future()
    try:
        fd = sys.stdin.fileno()
        loop.add_reader(fd, _wake, ready)
    except (OSError, ValueError, PermissionError):  # not selectable (a regular file)
        return sys.stdin.readline().strip()
    try:
        await ready
    finally:
        loop.remove_reader(fd)
    return sys.stdin.readline().strip()


def write_mapping(path: Path, data: dict[str, Any]) -> Path | None:
    """Validate, back up the old file to ``.bak``, write atomically. Returns the backup."""
    parse_mapping(data, str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    backup = None
    if path.exists():
        backup = path.with_name(path.name + ".bak")
        shutil.copy2(path, backup)
    tmp = path.with_name(path.name + ".tmp")
    header = "# Written by `lupin pad-calibrate`; the previous file is kept as .bak.\n"
    tmp.write_text(header + yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    os.replace(tmp, path)
    return backup


async def calibrate(reader: PadReader, layout: str, base: dict[str, Any]) -> dict[str, Any]:
    session = Session(reader)
    pump = asyncio.create_task(session.pump(), name="pad-calibrate-pump")
    try:
        answers = await session.run(STEPS[layout])
    finally:
        pump.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await pump
        await reader.close()
    return apply_answers(base, answers)


def main(args: argparse.Namespace) -> int:
    layout = args.pad_layout or resolve_layout(None)
    how = "forced" if args.pad_layout else "detected from /proc/bus/input/devices"
    path = Path(args.mapping_dir) / f"{layout}.yaml" if args.mapping_dir else override_path(layout)
    base = parse_mapping(read_yaml(path), str(path)) if path.exists() else load_mapping(layout)
    try:
        reader = open_pad(args.pad, layout=layout, grab=True)
    except (registry.AdapterNotFound, ValueError) as exc:
        say(f"lupin pad-calibrate: {exc}")
        return 2
    if reader is None:
        say("lupin pad-calibrate: --pad none: nothing to calibrate")
        return 2
    say(f"Calibrating {reader.name}, layout {layout} ({how}); teleop is not driving.")
    try:
        data = asyncio.run(
            calibrate(reader, layout, base.model_dump(mode="json", exclude_none=True))
        )
    except (Aborted, TimeoutError) as exc:
        say(f"calibration aborted: {exc or 'no frames from the pad'}; nothing written")
        return 1
    say(yaml.safe_dump(data, sort_keys=False))
    if not getattr(args, "yes", False):
        answer = input(f"Write {path}? [y/N] ").strip().lower()
        if answer not in ("y", "yes"):
            say("nothing written")
            return 1
    try:
        backup = write_mapping(path, data)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot write: {exc}") from None
    say(f"wrote {path}" + (f" (previous kept as {backup})" if backup else ""))
    return 0
