"""``lupin jog``: interactive per-joint jog, as a client of the running daemon's API.

Commands are typed at a ``jog>`` prompt, one per line, and read inside the
event loop (``bench_io.Terminal``), so the tool works the same at a terminal,
in a pseudo-terminal and from a pipe. Each move is one slider command
(``POST /api/arm/joints/{joint}``, the gripper's on the HMI scale): the daemon
clamps, gates on torque and the E-stop, and refuses with a reason, which is
printed. Steps are clamped to the joint's window here too, purely for
immediate feedback, as the seed's jog does; the daemon stays the authority.

``zero`` and ``home`` are different things (bring-up seed, "zero and home are
different things"): ``zero <joint>`` drives one joint to 0 rad, the middle of
its calibrated travel; ``home`` goes to the *taught* pose named ``home``, the
arm's rest position, exactly as ``lupin pose go home`` would.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass

from lupin import api_models as m
from lupin.api.client import ApiClient, ApiClientError
from lupin.cli.bench_io import Terminal
from lupin.cli.client_io import (
    EXIT_FAILED,
    EXIT_OK,
    get_robot,
    get_state,
    not_torqued,
    run_client,
    table,
)
from lupin.cli.pose import find

PROMPT = "jog> "
ZERO_NOTE = "0 rad, the joint's zero (not the taught home)"
STATUS_HEADER = ["joint", "now deg", "target deg", "window deg", "torque", "status"]
HOME = "home"

HELP = """\
commands, one per line:
  <joint> +          step the joint up by --step
  <joint> -          step it down
  <joint> <deg>      move it to an absolute angle in degrees
  zero <joint>       drive the joint to 0 rad (its calibrated zero, not the rest pose)
  home               go to the TAUGHT pose 'home' (the rest pose, not 0 rad), like
                     `lupin pose go home` with its default --max-travel and --speed
  torque on|off      hold the arm where it is / let it go limp (support it first)
  status             joints, positions, windows and torque
  help               this text
  quit               leave (or end of input); torque is left as it is
A joint may be given by a unique prefix (`elbow +`). The gripper uses the HMI's
scale, in degrees from open to closed, as the HMI's slider does."""


@dataclass(frozen=True)
class Axis:
    """One joint as jog shows and commands it: display degrees = offset + gain * joint rad."""

    name: str
    path: str
    window: tuple[float, float]  # display degrees, low to high
    gain: float = 180.0 / math.pi
    offset: float = 0.0
    hmi: bool = False

    def show(self, rad: float) -> float:
        return self.offset + self.gain * rad

    def clamp(self, value: float) -> float:
        return min(max(value, self.window[0]), self.window[1])


def axes(robot: m.RobotInfo) -> dict[str, Axis]:
    """Every joint of the robot; the gripper moves on the HMI scale through its own endpoint."""
    out = {}
    grip = robot.gripper
    for j in robot.joints:
        if grip is not None and j.name == grip.joint:
            # The daemon maps HMI degrees linearly: open end to open_rad, closed to closed_rad.
            gain = (grip.hmi_closed_deg - grip.hmi_open_deg) / (grip.closed_rad - grip.open_rad)
            lo, hi = sorted((grip.hmi_open_deg, grip.hmi_closed_deg))
            out[j.name] = Axis(
                j.name,
                "/api/arm/gripper",
                (lo, hi),
                gain=gain,
                offset=grip.hmi_open_deg - gain * grip.open_rad,
                hmi=True,
            )
        else:
            lo_i, hi_i = j.window_deg
            out[j.name] = Axis(j.name, f"/api/arm/joints/{j.name}", (float(lo_i), float(hi_i)))
    return out


def main(args: argparse.Namespace) -> int:
    async def body(client: ApiClient) -> int:
        robot = await get_robot(client)
        return await Jog(client, Terminal(False), robot, args.step).run()

    return run_client("jog", args.url, args.token, body)


class Jog:
    def __init__(
        self, client: ApiClient, term: Terminal, robot: m.RobotInfo, step_rad: float
    ) -> None:
        self.client = client
        self.term = term
        self.robot = robot
        self.step_rad = step_rad
        self.axes = axes(robot)
        # At a terminal the line discipline echoes what is typed; from a pipe, echo it here
        # so a transcript reads like a session.
        self.echo = not _isatty(term)

    async def run(self) -> int:
        self.term.say(
            f"lupin jog: {self.client.url} ({self.robot.profile}); step {self.step_rad} rad "
            f"({math.degrees(self.step_rad):.1f} deg). Type `help` for the commands."
        )
        await self.status()
        while True:
            print(PROMPT, end="", file=self.term.out, flush=True)
            line = await self.term.readline()
            if line is None:
                self.term.say("")
                break
            if self.echo:
                self.term.say(line)
            if not await self.command(line):
                break
        self.term.say("bye: torque is left as it is (`torque off` before quitting limps the arm)")
        return EXIT_OK

    async def command(self, line: str) -> bool:
        """Run one command line; False ends the session. Refusals are printed, not fatal."""
        words = line.split()
        if not words:
            return True
        try:
            return await self._dispatch(words)
        except ApiClientError as exc:
            if exc.exit_code != EXIT_FAILED:
                raise  # no daemon, no answer, or no permission: nothing more will work
            self.term.say(f"refused: {exc.reason} ({exc.code})" if exc.code else str(exc))
            if exc.code == "torque_off":
                self.term.say("  type `torque on` to enable it, then repeat the move")
            return True

    async def _dispatch(self, words: list[str]) -> bool:
        head, rest = words[0].lower(), words[1:]
        if head in ("quit", "exit", "q"):
            return False
        if head in ("help", "?"):
            self.term.say(HELP)
        elif head == "status" and not rest:
            await self.status()
        elif head == "torque" and len(rest) == 1 and rest[0].lower() in ("on", "off"):
            await self.torque(rest[0].lower() == "on")
        elif head == "home" and not rest:
            await self.home()
        elif head == "zero" and len(rest) == 1:
            axis = self.axis(rest[0])
            if axis is not None:
                await self.move(axis, axis.show(0.0), ZERO_NOTE)
        elif head == "zero":
            self.term.say("zero needs one joint: `zero <joint>` drives it to 0 rad")
        elif len(words) == 2:
            await self.jog(words[0], words[1])
        else:
            self.term.say(f"unknown command {' '.join(words)!r}: type `help`")
        return True

    def axis(self, text: str) -> Axis | None:
        """The joint named, or by a unique prefix; otherwise say which joints there are."""
        if text in self.axes:
            return self.axes[text]
        hits = [n for n in self.axes if n.startswith(text)]
        if len(hits) == 1:
            return self.axes[hits[0]]
        what = f"ambiguous joint {text!r} ({', '.join(hits)})" if hits else f"no joint {text!r}"
        self.term.say(f"{what}; joints: {', '.join(self.axes)}")
        return None

    async def jog(self, joint: str, how: str) -> None:
        axis = self.axis(joint)
        if axis is None:
            return
        if how in ("+", "-"):
            state = await get_state(self.client)
            base = _commanded_rad(state, axis.name)
            if base is None:
                self.term.say(f"{axis.name}: no position known yet; try again in a moment")
                return
            now = axis.show(base)
            step = abs(axis.gain) * self.step_rad
            wanted = now + step if how == "+" else now - step
            target = axis.clamp(wanted)
            if abs(target - now) < 1e-6:
                self.term.say(f"{axis.name} is at the edge of its window {_window(axis)}")
                return
            note = f"held at the window's edge {_window(axis)}" if target != wanted else ""
            await self.move(axis, target, note, state)
            return
        try:
            value = float(how)
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            self.term.say(f"{axis.name}: use `+`, `-` or an angle in degrees, not {how!r}")
            return
        await self.move(axis, value, "")

    async def move(
        self, axis: Axis, target: float, note: str, state: m.RobotState | None = None
    ) -> None:
        """One slider command, after checking torque so the operator learns how to enable it."""
        state = state or await get_state(self.client)
        if not_torqued(state, [axis.name]):
            self.term.say(_torque_advice(state, axis.name))
            return
        reply = m.MoveResponse.model_validate(
            await self.client.request("POST", axis.path, {"angle_deg": target})
        )
        unit = "deg (HMI)" if axis.hmi else "deg"
        extra = f"; {note}" if note else ""
        self.term.say(f"{axis.name} -> {target:.1f} {unit} in {reply.travel_s:.2f} s{extra}")

    async def torque(self, on: bool) -> None:
        reply = m.TorqueResponse.model_validate(
            await self.client.request("POST", "/api/arm/torque", {"enabled": on})
        )
        if on:
            self.term.say(f"torque: {reply.torque} (the arm holds where it is)")
        else:
            self.term.say(f"torque: {reply.torque} (the arm is limp: support it)")

    async def home(self) -> None:
        # Seed: "home" is a taught rest pose, not 0 rad; both were once called home and it
        # confused an operator, so say which one this is every time.
        pose = await find(self.client, HOME)
        if pose is None:
            self.term.say(
                "no taught pose named 'home'. home is the arm's taught rest pose, not 0 rad: "
                "teach it by posing the arm and running `lupin pose save home`. "
                "To drive a joint to 0 rad, use `zero <joint>`."
            )
            return
        state = await get_state(self.client)
        off = not_torqued(state, pose.joints_rad)
        if off:
            self.term.say(_torque_advice(state, ", ".join(off)))
            return
        try:
            reply = m.PoseGoResponse.model_validate(
                await self.client.request(
                    "POST", f"/api/arm/poses/{HOME}/go", m.PoseGoRequest().model_dump()
                )
            )
        except ApiClientError as exc:
            if exc.code == "too_far":
                self.term.say(f"refused: {exc.reason} ({exc.code})")
                self.term.say(
                    "  for a known-long move, `lupin pose go home --max-travel RAD` shows the "
                    "travel and asks first"
                )
                return
            raise
        self.term.say(
            f"going to the taught pose 'home' (not 0 rad): largest joint travel "
            f"{reply.largest_travel_rad:.3f} rad, {reply.travel_s:.1f} s"
        )

    async def status(self) -> None:
        state = await get_state(self.client)
        rows = []
        for j in state.joints:
            axis = self.axes.get(j.name)
            if axis is None:
                continue
            now = None if j.position_deg is None else axis.show(math.radians(j.position_deg))
            cmd = None if j.commanded_deg is None else axis.show(math.radians(j.commanded_deg))
            status = j.status if j.excluded is None else f"excluded: {j.excluded}"
            rows.append(
                [
                    f"{j.name} (HMI)" if axis.hmi else j.name,
                    _fmt(now),
                    _fmt(cmd),
                    _window(axis),
                    j.torque,
                    status,
                ]
            )
        self.term.say(table(STATUS_HEADER, rows))
        estop = "ENGAGED" if state.estop else "released"
        self.term.say(f"torque: {state.torque}; E-stop: {estop}")


def _commanded_rad(state: m.RobotState, joint: str) -> float | None:
    """Where the daemon holds the joint: steps add to the target, not to a drooping reading."""
    for j in state.joints:
        if j.name == joint:
            value = j.commanded_deg if j.commanded_deg is not None else j.position_deg
            return None if value is None else math.radians(value)
    return None


def _torque_advice(state: m.RobotState, joints: str) -> str:
    if state.estop:
        return f"torque is off for {joints} and the E-stop is engaged: release it, then `torque on`"
    if state.torque == "enabling":
        return f"torque is still coming on for {joints}: try again in a moment"
    return (
        f"torque is off for {joints}: nothing moves until it is on. "
        "Type `torque on` (the arm then holds where it is), then repeat the move."
    )


def _window(axis: Axis) -> str:
    return f"[{axis.window[0]:g}, {axis.window[1]:g}]"


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"


def _isatty(term: Terminal) -> bool:
    try:
        return term.stdin.isatty()
    except (AttributeError, ValueError):
        return False
