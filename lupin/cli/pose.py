"""``lupin pose save|list|go|limits|delete``: taught poses, as a client of the daemon's API.

The bring-up seed's "Named poses": pose the limp arm by hand, capture it, and
later command it back. ``save`` is a read-only capture; ``go`` is the only
subcommand that moves, and it shows the largest joint travel and asks first.
Replacing or forgetting a taught pose also asks (``--yes`` for scripts): a
pose is a measurement of one arm that nothing else can give back.
The travel guard (``--max-travel``, 0.35 rad) and the streamed speed
(``--speed``, 0.5 rad/s) are the daemon's; this client passes them on and
prints the daemon's refusal when it says no. ``limits`` prints the envelope the
taught poses span, with the seed's warning that it is not the calibration path.
"""

from __future__ import annotations

import argparse
import math
import sys

from pydantic import ValidationError

from lupin import api_models as m
from lupin.api.client import ApiClient, ApiClientError
from lupin.cli.bench_io import Terminal
from lupin.cli.client_io import (
    EXIT_FAILED,
    EXIT_OK,
    UsageError,
    deg,
    get_robot,
    get_state,
    not_torqued,
    ordered,
    run_client,
    table,
)
from lupin.poses import NAME, envelope

NEEDS_NAME = ("save", "go", "delete")
# A span under this is the seed's "joint that barely moved between two poses": flagged.
NARROW_SPAN_RAD = 0.05
# The go request's fields and the flags that set them, to name the flag in a refusal.
FLAGS = {"max_travel_rad": "--max-travel", "speed_rad_s": "--speed"}
TORQUE_ADVICE = "enable torque first: `torque on` in `lupin jog`, or POST /api/arm/torque"


def main(args: argparse.Namespace) -> int:
    return run_client("pose", args.url, args.token, lambda client: run(client, args))


def check_usage(args: argparse.Namespace) -> None:
    """Refuse a missing, extra or malformed name before anything is sent (exit 2)."""
    if args.action in NEEDS_NAME:
        if args.name is None:
            raise UsageError(f"pose {args.action} needs a pose NAME")
        if not NAME.match(args.name):
            raise UsageError(f"bad pose name {args.name!r}: 1-40 of A-Z a-z 0-9 _ -")
    elif args.name is not None:
        raise UsageError(f"pose {args.action} takes no NAME (got {args.name!r})")


async def run(client: ApiClient, args: argparse.Namespace) -> int:
    check_usage(args)
    term = Terminal(args.yes)
    if args.action == "save":
        return await save(client, args.name, term)
    if args.action == "list":
        return await list_poses(client, args.max_travel, term)
    if args.action == "go":
        return await go(client, args, term)
    if args.action == "limits":
        return await limits(client, term)
    return await delete(client, args.name, term)


def _path(name: str) -> str:
    return f"/api/arm/poses/{name}"  # NAME-checked: nothing to escape


async def find(client: ApiClient, name: str) -> m.Pose | None:
    try:
        return m.Pose.model_validate(await client.request("GET", _path(name)))
    except ApiClientError as exc:
        if exc.code == "unknown_pose":
            return None
        raise


async def save(client: ApiClient, name: str, term: Terminal) -> int:
    robot = await get_robot(client)
    before = await find(client, name)
    if before is not None:
        # A taught pose is one arm's measurement: replacing it is asked, never assumed.
        term.say(f"pose {name!r} is already taught:")
        term.say(_indent(pose_table(before, robot)))
        if not await term.confirm(f"Replace {name!r} with the arm's pose now?"):
            term.say(f"Kept pose {name!r} as it was.")
            return EXIT_FAILED
    # An empty body asks the daemon to capture the measured pose: nothing is written to a servo.
    pose = m.Pose.model_validate(await client.request("PUT", _path(name), {}))
    verb = "replaced" if before is not None else "saved"
    term.say(f"{verb} pose {name!r}: a read-only capture of the measured pose (nothing moved)")
    term.say(_indent(pose_table(pose, robot)))
    return EXIT_OK


def pose_table(pose: m.Pose, robot: m.RobotInfo) -> str:
    rows = [
        [j, deg(pose.joints_rad[j]), f"{pose.joints_rad[j]:.4f}"]
        for j in ordered(pose.joints_rad, robot)
    ]
    return table(["joint", "deg", "rad"], rows)


async def list_poses(client: ApiClient, max_travel: float, term: Terminal) -> int:
    robot = await get_robot(client)
    poses = m.PoseList.model_validate(await client.request("GET", "/api/arm/poses")).poses
    if not poses:
        term.say("no taught poses yet: pose the arm, then `lupin pose save NAME`")
        return EXIT_OK
    joints = ordered({j for p in poses for j in p.joints_rad}, robot)
    rows, far = [], False
    for p in poses:
        cells = [deg(p.joints_rad[j]) if j in p.joints_rad else "-" for j in joints]
        if p.distance_rad is None:
            dist = "?"
        else:
            over = p.distance_rad > max_travel
            far = far or over
            dist = f"{p.distance_rad:.3f}" + (" >" if over else "  ")
        rows.append([p.name, *cells, dist])
    term.say(table(["pose", *joints, "from here (rad)"], rows))
    term.say("joints in degrees; 'from here' is the largest joint distance from the measured pose")
    if far:
        term.say(
            f"> farther than --max-travel {max_travel} rad: `lupin pose go` refuses it unless "
            "--max-travel is raised deliberately"
        )
    return EXIT_OK


def preview(
    pose: m.Pose, robot: m.RobotInfo, state: m.RobotState
) -> list[tuple[str, float, float]]:
    """(joint, now, goal) in radians, as the daemon will judge the travel.

    The daemon measures travel from its commanded pose to the pose clamped into
    each joint's window; the measured position stands in before anything is
    commanded.
    """
    windows = {j.name: j.window_deg for j in robot.joints}
    now = {
        j.name: j.commanded_deg if j.commanded_deg is not None else j.position_deg
        for j in state.joints
    }
    out = []
    for joint in ordered(pose.joints_rad, robot):
        here = now.get(joint)
        if here is None or joint not in windows:
            continue
        lo, hi = (math.radians(v) for v in windows[joint])
        goal = min(max(pose.joints_rad[joint], lo), hi)
        out.append((joint, math.radians(here), goal))
    return out


async def go(client: ApiClient, args: argparse.Namespace, term: Terminal) -> int:
    try:
        request = m.PoseGoRequest(max_travel_rad=args.max_travel, speed_rad_s=args.speed)
    except ValidationError as exc:
        problems = "; ".join(
            f"{FLAGS.get(str(e['loc'][0]), e['loc'][0])}: {e['msg']}" for e in exc.errors()
        )
        raise UsageError(problems) from None
    name = args.name
    pose = await find(client, name)
    if pose is None:
        print(f"lupin pose: no taught pose {name!r} (see `lupin pose list`)", file=sys.stderr)
        return EXIT_FAILED
    robot, state = await get_robot(client), await get_state(client)
    plan = preview(pose, robot, state)
    rows = [[j, deg(a), deg(b), f"{abs(b - a):.3f}"] for j, a, b in plan]
    term.say(f"pose {name!r}:")
    term.say(_indent(table(["joint", "now deg", "pose deg", "travel rad"], rows)))
    if plan:
        joint, a, b = max(plan, key=lambda p: abs(p[2] - p[1]))
        travel = abs(b - a)
        term.say(
            f"largest joint travel: {travel:.3f} rad ({deg(travel)} deg) on {joint}; "
            f"--max-travel {args.max_travel} rad, --speed {args.speed} rad/s "
            f"(about {travel / args.speed:.1f} s)"
        )
        if travel > args.max_travel:
            # Said before asking; the daemon is still the one that refuses.
            term.say(
                "that is over --max-travel: the daemon will refuse it. Raise --max-travel "
                "deliberately for a known-long move."
            )
    off = not_torqued(state, pose.joints_rad)
    if off:
        term.say(f"torque is not on for {', '.join(off)}: the daemon will refuse; {TORQUE_ADVICE}")
    if not await term.confirm("move?"):
        term.say("Nothing moved.")
        return EXIT_FAILED
    try:
        reply = m.PoseGoResponse.model_validate(
            await client.request("POST", _path(name) + "/go", request.model_dump())
        )
    except ApiClientError as exc:
        if exc.code == "torque_off":
            print(f"lupin pose: {exc}; {TORQUE_ADVICE}", file=sys.stderr, flush=True)
            return EXIT_FAILED
        raise
    term.say(
        f"going to {name!r}: largest joint travel {reply.largest_travel_rad:.3f} rad, "
        f"{reply.travel_s:.1f} s at {args.speed} rad/s"
    )
    return EXIT_OK


async def limits(client: ApiClient, term: Terminal) -> int:
    robot = await get_robot(client)
    poses = m.PoseList.model_validate(await client.request("GET", "/api/arm/poses")).poses
    if not poses:
        print("lupin pose: no taught poses: there is no envelope to span", file=sys.stderr)
        return EXIT_FAILED
    term.say(limits_yaml(poses, robot))
    return EXIT_OK


def limits_yaml(poses: list[m.Pose], robot: m.RobotInfo) -> str:
    """The spanned envelope as YAML, with the seed's warning carried in the comments."""
    spans = envelope(p.joints_rad for p in poses)
    windows = {j.name: j.window_deg for j in robot.joints}
    names = ", ".join(p.name for p in poses)
    lines = [
        f"# lupin pose limits: the envelope spanned by {len(poses)} taught poses ({names}).",
        "# NOT the calibration path: it describes only where the arm has already been and never",
        "# learns where the stops are, so a joint that barely moved between poses gets a",
        "# near-zero band. Take the hard-stop limits from `lupin calibrate` first; use these",
        "# only to narrow a working envelope inside them. Radians are about each joint's zero.",
        "# envelope_deg is the profile's symmetric narrowing (arm.joints[].envelope_deg) that",
        "# covers the span; window_deg is the joint's window today.",
        "joints:",
    ]
    for joint in ordered(spans, robot):
        lo, hi = spans[joint]
        cover = max(1, math.ceil(max(abs(math.degrees(lo)), abs(math.degrees(hi))) - 1e-9))
        lines.append(f"  {joint}:")
        if hi - lo < NARROW_SPAN_RAD:
            span = f"{hi - lo:.3f}"
            lines.append(f"    # barely moved between the poses ({span} rad): a near-zero band")
        lines += [
            f"    min_rad: {lo:.4f}",
            f"    max_rad: {hi:.4f}",
            f"    min_deg: {math.degrees(lo):.1f}",
            f"    max_deg: {math.degrees(hi):.1f}",
            f"    envelope_deg: {min(cover, 180)}",
        ]
        if joint in windows:
            a, b = windows[joint]
            lines.append(f"    window_deg: [{a}, {b}]")
    return "\n".join(lines)


async def delete(client: ApiClient, name: str, term: Terminal) -> int:
    pose = await find(client, name)
    if pose is None:
        print(f"lupin pose: no taught pose {name!r} (see `lupin pose list`)", file=sys.stderr)
        return EXIT_FAILED
    term.say(f"pose {name!r}:")
    term.say(_indent(pose_table(pose, await get_robot(client))))
    if not await term.confirm(f"Forget pose {name!r}?"):
        term.say(f"Kept pose {name!r}.")
        return EXIT_FAILED
    await client.request("DELETE", _path(name))
    term.say(f"deleted pose {name!r} (the previous poses file is kept as poses.yaml.bak)")
    return EXIT_OK


def _indent(text: str) -> str:
    return "\n".join("  " + line for line in text.split("\n"))
