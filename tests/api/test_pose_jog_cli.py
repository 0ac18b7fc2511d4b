"""``lupin pose`` and ``lupin jog`` end to end: subprocess clients of a real daemon on the sim.

The daemon and the simulated servos run in the test's event loop (the ``api``
fixture), so a test can move a limp joint by hand, read every packet the servos
got and look at the daemon's commanded pose; the CLIs run as ``python -m
lupin ...``, with a pipe for stdin or, for jog, on a pseudo-terminal the test
types into, as an operator would.
"""

from __future__ import annotations

import asyncio
import math
import re
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path

import aiohttp
import pytest
import yaml

from lupin.api import ApiServer
from lupin.daemon import Daemon
from lupin.joints import RAD_PER_COUNT
from lupintest.harness import Sim, child_env, wait_for
from lupintest.pty_tool import PtyTool

from .conftest import TOKEN
from .helpers import call, free_port, lupin, torque_on

ELBOW_ID = 3


def commanded(daemon: Daemon, joint: str = "elbow_flex") -> float:
    assert daemon.arm.commanded is not None
    return daemon.arm.commanded[joint]


async def put_pose(
    http: aiohttp.ClientSession, api: ApiServer, name: str, joints_rad: dict[str, float]
) -> None:
    status, data = await call(
        http, api, "PUT", f"/api/arm/poses/{name}", {"joints_rad": joints_rad}
    )
    assert status == 200, data


async def by_hand(sim: Sim, daemon: Daemon, counts_from_zero: int) -> float:
    """Move the limp elbow by hand; return the angle once the daemon has measured it."""
    sim.bus.servo(ELBOW_ID).move_by_hand(2048 + counts_from_zero)
    rad = counts_from_zero * RAD_PER_COUNT
    await wait_for(lambda: abs(daemon.arm.measured["elbow_flex"] - rad) < 1e-6)
    return rad


# -- lupin pose ---------------------------------------------------------------------------


async def test_pose_save_list_delete(
    api: ApiServer, sim: Sim, daemon: Daemon, lupin_home: Path
) -> None:
    url = ("--url", api.url)
    code, out, err = await lupin(lupin_home, "pose", "list", *url)
    assert code == 0 and "no taught poses" in out, err

    # Pose the limp arm by hand, then capture it: a read-only capture writes nothing.
    reach = await by_hand(sim, daemon, 130)
    t0 = time.monotonic()
    code, out, err = await lupin(lupin_home, "pose", "save", "reach", *url)
    assert code == 0, err
    assert "saved pose 'reach'" in out and "nothing moved" in out
    assert re.search(rf"elbow_flex\s+{math.degrees(reach):.1f}\s+{reach:.4f}", out), out
    assert sim.bus.writes(since=t0) == []
    stored = yaml.safe_load((lupin_home / "poses.yaml").read_text())["poses"]["reach"]
    assert stored["elbow_flex"] == pytest.approx(reach, abs=1e-6)
    assert "gripper" not in stored

    # Replacing a taught pose is asked; no answer (or no) keeps it as it was.
    await by_hand(sim, daemon, 60)
    code, out, err = await lupin(lupin_home, "pose", "save", "reach", *url)
    assert code == 1, err
    assert "pose 'reach' is already taught" in out and "Kept pose 'reach'" in out
    again = yaml.safe_load((lupin_home / "poses.yaml").read_text())["poses"]["reach"]
    assert again["elbow_flex"] == pytest.approx(reach, abs=1e-6)
    code, out, err = await lupin(lupin_home, "pose", "save", "reach", *url, stdin="y\n")
    assert code == 0 and "replaced pose 'reach'" in out, err
    replaced = yaml.safe_load((lupin_home / "poses.yaml").read_text())["poses"]["reach"]
    assert replaced["elbow_flex"] == pytest.approx(60 * RAD_PER_COUNT, abs=1e-6)
    reach = await by_hand(sim, daemon, 130)
    code, out, err = await lupin(lupin_home, "pose", "save", "reach", "--yes", *url)
    assert code == 0 and "yes (--yes)" in out and "replaced pose 'reach'" in out, err

    # Back at zero, the list shows each joint in degrees and how far away the pose is.
    await by_hand(sim, daemon, 0)
    code, out, err = await lupin(lupin_home, "pose", "list", *url)
    assert code == 0, err
    header, row = out.splitlines()[:2]
    assert header.split()[:7] == [
        "pose",
        "shoulder_pan",
        "shoulder_lift",
        "elbow_flex",
        "wrist_flex",
        "wrist_roll",
        "from",
    ]
    cells = row.split()
    assert cells[0] == "reach" and cells[3] == f"{math.degrees(reach):.1f}"
    assert float(cells[6]) == pytest.approx(reach, abs=1e-3)
    assert ">" not in row  # 0.2 rad is inside the default --max-travel 0.35

    # Forgetting a pose is asked too; --yes answers for a script.
    code, out, err = await lupin(lupin_home, "pose", "delete", "reach", *url, stdin="n\n")
    assert code == 1 and "Forget pose 'reach'? [y/N]" in out and "Kept pose 'reach'" in out
    assert "reach" in yaml.safe_load((lupin_home / "poses.yaml").read_text())["poses"]
    code, out, err = await lupin(lupin_home, "pose", "delete", "reach", "--yes", *url)
    assert code == 0 and "deleted pose 'reach'" in out, err
    assert "reach" in yaml.safe_load((lupin_home / "poses.yaml.bak").read_text())["poses"]
    code, out, err = await lupin(lupin_home, "pose", "delete", "reach", "--yes", *url)
    assert code == 1 and "no taught pose 'reach'" in err and "Traceback" not in err
    code, out, err = await lupin(lupin_home, "pose", "list", *url)
    assert code == 0 and "no taught poses" in out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["pose", "save"], "needs a pose NAME"),
        (["pose", "go"], "needs a pose NAME"),
        (["pose", "delete"], "needs a pose NAME"),
        (["pose", "save", "bad name"], "bad pose name"),
        (["pose", "save", "x" * 41], "bad pose name"),
        (["pose", "list", "extra"], "takes no NAME"),
        (["pose", "limits", "extra"], "takes no NAME"),
        (["pose", "go", "x", "--max-travel", "9"], "--max-travel"),
        (["pose", "go", "x", "--speed", "5"], "--speed"),
        (["pose", "go", "x", "--max-travle", "1"], "unrecognized arguments"),
        (["pose", "teach", "x"], "invalid choice"),
        (["jog", "--step", "0"], "must be above 0"),
    ],
)
async def test_usage_errors_exit_2_before_anything_is_sent(
    lupin_home: Path, args: list[str], message: str
) -> None:
    # No daemon listens here: exit 2 rather than 69 shows nothing was sent.
    url = f"http://127.0.0.1:{free_port()}"
    code, out, err = await lupin(lupin_home, *args, "--url", url)
    assert code == 2, (out, err)
    assert message in err and "Traceback" not in err


async def test_pose_go_asks_guards_and_moves(
    api: ApiServer, daemon: Daemon, http: aiohttp.ClientSession, lupin_home: Path
) -> None:
    url = ("--url", api.url)
    await torque_on(http, api)
    await put_pose(http, api, "reach", {"elbow_flex": 0.2, "wrist_flex": -0.1})
    await put_pose(http, api, "far", {"elbow_flex": -1.0})
    start = commanded(daemon)

    # Answering no at the prompt moves nothing.
    code, out, err = await lupin(lupin_home, "pose", "go", "reach", *url, stdin="n\n")
    assert code == 1, err
    assert "largest joint travel: 0.200 rad" in out and "on elbow_flex" in out
    assert "move? [y/N]" in out and "Nothing moved." in out
    await asyncio.sleep(0.1)
    assert commanded(daemon) == start
    # End of input is no, too.
    code, out, err = await lupin(lupin_home, "pose", "go", "reach", *url, stdin="")
    assert code == 1 and "taken as no" in out
    assert commanded(daemon) == start

    # Over --max-travel: said before asking, then refused by the daemon with its reason.
    code, out, err = await lupin(lupin_home, "pose", "go", "far", "--yes", *url)
    assert code == 1
    assert "over --max-travel" in out
    assert "too_far" in err and "exceeds max_travel 0.35" in err
    assert commanded(daemon) == start

    code, out, err = await lupin(lupin_home, "pose", "go", "nope", "--yes", *url)
    assert code == 1 and "no taught pose 'nope'" in err

    # --yes goes, at the given speed; the daemon's commanded pose is the taught one.
    code, out, err = await lupin(lupin_home, "pose", "go", "reach", "--yes", "--speed", "1.0", *url)
    assert code == 0, err
    assert "move? [y/N] yes (--yes)" in out and "going to 'reach'" in out
    assert commanded(daemon) == pytest.approx(0.2)
    assert commanded(daemon, "wrist_flex") == pytest.approx(-0.1)
    await wait_for(lambda: abs(daemon.arm.measured["elbow_flex"] - 0.2) < 0.03, timeout=5)

    # A deliberately raised --max-travel lets the long move through.
    code, out, err = await lupin(
        lupin_home, "pose", "go", "far", "--yes", "--max-travel", "1.5", "--speed", "3", *url
    )
    assert code == 0, err
    assert commanded(daemon) == pytest.approx(-1.0)

    # Torque off: the daemon refuses; the client says how to enable it.
    status, _ = await call(http, api, "POST", "/api/arm/torque", {"enabled": False})
    assert status == 200
    code, out, err = await lupin(lupin_home, "pose", "go", "reach", "--yes", *url)
    assert code == 1
    assert "torque is not on" in out
    assert "torque_off" in err and "torque on" in err


async def test_pose_limits_spans_the_taught_poses(
    api: ApiServer, http: aiohttp.ClientSession, lupin_home: Path
) -> None:
    url = ("--url", api.url)
    code, out, err = await lupin(lupin_home, "pose", "limits", *url)
    assert code == 1 and "no taught poses" in err

    await put_pose(http, api, "a", {"elbow_flex": 0.2, "wrist_flex": -0.1})
    await put_pose(http, api, "b", {"elbow_flex": -0.3, "wrist_flex": -0.1, "shoulder_pan": 0.5})
    code, out, err = await lupin(lupin_home, "pose", "limits", *url)
    assert code == 0, err
    # The seed's warning travels with the YAML, as comments.
    assert "NOT the calibration path" in out and "lupin calibrate" in out
    assert "narrow" in out
    doc = yaml.safe_load(out)
    joints = doc["joints"]
    assert list(joints) == ["shoulder_pan", "elbow_flex", "wrist_flex"]  # the robot's order
    assert joints["elbow_flex"] == {
        "min_rad": -0.3,
        "max_rad": 0.2,
        "min_deg": -17.2,
        "max_deg": 11.5,
        "envelope_deg": 18,
        "window_deg": [-90, 90],
    }
    assert joints["shoulder_pan"]["min_rad"] == joints["shoulder_pan"]["max_rad"] == 0.5
    # A joint that never moved between the poses is flagged as a near-zero band.
    wrist = out[out.index("  wrist_flex:") :]
    assert "near-zero band" in wrist.splitlines()[1]
    assert "near-zero band" not in out[out.index("  elbow_flex:") : out.index("  wrist_flex:")]


async def test_pose_go_in_a_terminal(
    api: ApiServer, daemon: Daemon, http: aiohttp.ClientSession, lupin_home: Path
) -> None:
    """At a real terminal: the travel table, the question, and a typed answer."""
    await torque_on(http, api)
    await put_pose(http, api, "reach", {"elbow_flex": 0.25})
    args = ("pose", "go", "reach", "--url", api.url, "--speed", "1.0")

    tool = PtyTool(args, child_env(lupin_home))
    try:
        shown = await tool.expect("move? [y/N]")
        assert re.search(r"elbow_flex\s+0\.0\s+14\.3\s+0\.250", shown), shown
        assert "largest joint travel: 0.250 rad" in shown
        tool.send("n\n")
        assert await tool.wait() == 1
        assert "Nothing moved." in tool.output
    finally:
        await tool.close()
    assert commanded(daemon) == 0.0

    tool = PtyTool(args, child_env(lupin_home))
    try:
        await tool.expect("move? [y/N]")
        tool.send("y\n")
        assert await tool.wait() == 0, tool.output
        assert "going to 'reach'" in tool.output
    finally:
        await tool.close()
    assert commanded(daemon) == pytest.approx(0.25)
    await wait_for(lambda: abs(daemon.arm.measured["elbow_flex"] - 0.25) < 0.03, timeout=5)


# -- lupin jog ----------------------------------------------------------------------------


class PtyJog(PtyTool):
    """``lupin jog`` on a pty: each line typed waits for the next ``jog>`` prompt."""

    async def type(self, line: str, until: str = "jog> ") -> str:
        return await super().type(line, until)


@pytest.fixture()
async def jog(api: ApiServer, lupin_home: Path) -> AsyncIterator[Callable[..., PtyJog]]:
    """``jog(*args)`` starts jog on a pty against ``api``; killed (if need be) and reaped."""
    started: list[PtyJog] = []

    def start(*args: str) -> PtyJog:
        tool = PtyJog(("jog", "--url", api.url, *args), child_env(lupin_home))
        started.append(tool)
        return tool

    try:
        yield start
    finally:
        for tool in started:
            await tool.close()


async def test_jog_in_a_terminal(jog: Callable[..., PtyJog], daemon: Daemon, sim: Sim) -> None:
    tool = jog()
    banner = await tool.expect_next("jog> ")
    assert "step 0.05 rad" in banner
    assert re.search(r"elbow_flex\s+0\.0\s+0\.0\s+\[-90, 90\]\s+off", banner), banner
    assert "gripper (HMI)" in banner and "[-30, 30]" in banner

    # Torque is checked before moving, and the operator is told how to enable it.
    start = commanded(daemon)
    t0 = time.monotonic()
    said = await tool.type("elbow_flex +")
    assert "torque is off for elbow_flex" in said and "`torque on`" in said
    assert commanded(daemon) == start and sim.bus.writes(since=t0) == []

    assert "torque: on" in await tool.type("torque on")

    # A step is one slider command from where the joint is commanded to be.
    said = await tool.type("elbow_flex +")
    assert "elbow_flex -> 2.9 deg" in said
    assert commanded(daemon) == pytest.approx(0.05)
    await wait_for(lambda: abs(daemon.arm.measured["elbow_flex"] - 0.05) < 0.02, timeout=5)
    said = await tool.type("elbow -")  # a unique prefix names the joint
    assert "elbow_flex -> 0.0 deg" in said
    assert commanded(daemon) == pytest.approx(0.0)

    assert "elbow_flex -> 12.0 deg" in await tool.type("elbow_flex 12")
    assert commanded(daemon) == pytest.approx(math.radians(12))
    await wait_for(lambda: abs(daemon.arm.measured["elbow_flex"] - 0.209) < 0.03, timeout=5)

    # zero drives the joint to 0 rad.
    said = await tool.type("zero elbow_flex")
    assert "elbow_flex -> 0.0 deg" in said and "0 rad" in said
    assert commanded(daemon) == 0.0
    await wait_for(lambda: abs(daemon.arm.measured["elbow_flex"]) < 0.02, timeout=5)

    # home is the taught rest pose, never 0 rad; without one it says so and points at zero.
    said = await tool.type("home")
    assert "no taught pose named 'home'" in said and "not 0 rad" in said
    assert "zero <joint>" in said and "lupin pose save home" in said

    # The daemon's refusals are printed with their reasons, and jog carries on.
    said = await tool.type("elbow_flex 500")
    assert "refused: elbow_flex: 500.0 deg is outside [-90, 90] (out_of_window)" in said
    assert commanded(daemon) == 0.0
    said = await tool.type("wrist +")
    assert "ambiguous joint 'wrist'" in said
    assert "no joint 'knee'" in await tool.type("knee 3")
    assert "type `help`" in await tool.type("dance")
    assert "zero <joint>" in await tool.type("help")
    said = await tool.type("status")
    assert re.search(r"elbow_flex\s+-?\d+\.\d\s+0\.0\s+\[-90, 90\]\s+on", said), said

    # Torque off limps the arm; the next move is stopped before it is sent.
    assert "torque: off" in await tool.type("torque off")
    said = await tool.type("elbow_flex 5")
    assert "torque is off for elbow_flex" in said

    await tool.type("quit", until="bye")
    assert await tool.wait() == 0


async def test_jog_home_goes_to_the_taught_pose_from_a_pipe(
    api: ApiServer, daemon: Daemon, http: aiohttp.ClientSession, lupin_home: Path
) -> None:
    await torque_on(http, api)
    await put_pose(http, api, "home", {"elbow_flex": 0.15, "wrist_flex": -0.1})
    # Commands from a pipe, one per line; end of input ends the session.
    code, out, err = await lupin(lupin_home, "jog", "--url", api.url, stdin="home\nstatus\n")
    assert code == 0, err
    assert "jog> home\n" in out  # echoed, since a pipe does not echo
    assert "going to the taught pose 'home' (not 0 rad)" in out
    assert "largest joint travel 0.150 rad" in out
    assert commanded(daemon) == pytest.approx(0.15)
    assert commanded(daemon, "wrist_flex") == pytest.approx(-0.1)

    # A home farther than the default travel guard is refused, with the way round it.
    await put_pose(http, api, "home", {"elbow_flex": -1.2})
    code, out, err = await lupin(lupin_home, "jog", "--url", api.url, stdin="home\nquit\n")
    assert code == 0, err
    assert "(too_far)" in out and "--max-travel" in out
    assert commanded(daemon) == pytest.approx(0.15)


# -- no daemon, and the token --------------------------------------------------------------


@pytest.mark.parametrize(
    "args", [["pose", "list"], ["pose", "save", "x"], ["pose", "go", "x", "--yes"], ["jog"]]
)
async def test_no_daemon_exits_69(lupin_home: Path, args: list[str]) -> None:
    url = f"http://127.0.0.1:{free_port()}"
    code, _out, err = await lupin(lupin_home, *args, "--url", url, stdin="")
    assert code == 69
    assert f"no Lupin daemon answering at {url}" in err and "lupin run" in err
    assert "Traceback" not in err


async def test_a_token_is_needed_to_change_anything(api_token: ApiServer, lupin_home: Path) -> None:
    url = ("--url", api_token.url)
    code, _out, err = await lupin(lupin_home, "pose", "save", "rest", *url)
    assert code == 77 and "LUPIN_TOKEN" in err
    code, out, err = await lupin(lupin_home, "pose", "save", "rest", *url, token=TOKEN)
    assert code == 0 and "saved pose 'rest'" in out, err
    # Reads stay open; jog stops at the first refused write rather than carrying on.
    code, out, err = await lupin(lupin_home, "pose", "list", *url)
    assert code == 0 and "rest" in out
    code, out, err = await lupin(lupin_home, "jog", *url, stdin="torque on\nstatus\n")
    assert code == 77 and "unauthorized" in err
    assert "jog> status" not in out
    assert TOKEN not in out + err
