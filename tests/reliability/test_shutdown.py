"""Shutdown and restart, mid-motion and under load, judged by the packets the servos received.

``tests/integration/test_daemon_process.py`` stops an idle daemon whose servos
were energised behind its back; ``tests/ops/test_stop_helper.py`` kills one
during auto-home. Here the daemon itself is driving: the wheels turn on a
stream of HMI twists, the arm follows a slider, and clients hammer the HTTP API
and the WebSocket the whole time. Then:

* SIGTERM: the wheels are zeroed, every servo goes limp and nothing is written
  after that, and the process exits 0 within 1 s;
* SIGKILL, then ``lupin stop-helper`` as systemd's ExecStopPost: wheels zero,
  every servo limp;
* restart under load on the same pty and port (after a clean stop, after the
  helper, and after a SIGKILL nobody cleaned up): the new daemon comes up and
  sends nothing at all, so no arm servo gets a goal or a torque write and no
  wheel is energised, until an operator's first command; a wheel a dead
  predecessor left spinning is stopped.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import signal
import time
from collections.abc import AsyncIterator
from pathlib import Path

import aiohttp

from lupin.base import BaseDrive
from lupin.mux import Twist
from lupin_adapters.sim.bus import WriteRecord
from lupintest.harness import Sim, child_env, lupin_cmd, wait_for

from .helpers import (
    ALL,
    ARM,
    GOAL_POS,
    TORQUE,
    WHEELS,
    DaemonProcess,
    MergedDaemonProcess,
    free_port,
    get_json,
    post,
)

DRIVE = {"source": "manual", "linear_x": 0.1, "angular_z": 0.3}
ELBOW, LIFT = 3, 2
# What systemd hands ExecStopPost after a SIGKILL of the main process.
KILLED = {"SERVICE_RESULT": "signal", "EXIT_CODE": "killed", "EXIT_STATUS": "KILL"}


def wheel_goals(sim: Sim) -> dict[int, int]:
    assert sim.profile.base is not None
    base = BaseDrive(sim.profile.base)
    twist = Twist(linear_x=DRIVE["linear_x"], angular_z=DRIVE["angular_z"])  # type: ignore[arg-type]
    base.command(twist, 0.0)
    return base.wheel_goals(0.0)


# -- load: clients that hammer the API across stops and restarts --------------------------


class Load:
    """HTTP and WebSocket clients that never command motion, and never give up.

    Reads (state, health, metrics), zero twists from ``auto``, a slider for a joint
    that does not exist, WebSocket clients reading state and sending zero twists;
    each reconnects as soon as it can. ``ok`` and ``failed`` count per phase.
    """

    def __init__(self, url: str) -> None:
        self.url = url
        self.ok = 0
        self.failed = 0
        self.statuses: set[int] = set()
        self._tasks: list[asyncio.Task[None]] = []
        self._session: aiohttp.ClientSession | None = None

    async def __aenter__(self) -> Load:
        self._session = aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=2))
        for n in range(4):
            self._tasks.append(asyncio.create_task(self._http(n)))
        for _ in range(2):
            self._tasks.append(asyncio.create_task(self._ws()))
        return self

    async def __aexit__(self, *exc: object) -> None:
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        assert self._session is not None
        await self._session.close()

    def take(self) -> tuple[int, int]:
        counts = (self.ok, self.failed)
        self.ok = self.failed = 0
        return counts

    async def _http(self, n: int) -> None:
        assert self._session is not None
        calls = [
            ("GET", "/api/state", None),
            ("POST", "/api/base/twist", {"source": "auto"}),
            ("GET", "/metrics", None),
            ("POST", "/api/arm/joints/no_such_joint", {"angle_deg": 10.0}),
            ("GET", "/api/health", None),
        ]
        i = n
        while True:
            method, path, body = calls[i % len(calls)]
            i += 1
            try:
                async with self._session.request(method, self.url + path, json=body) as resp:
                    await resp.read()
                    self.statuses.add(resp.status)
                    self.ok += 1
            except (aiohttp.ClientError, TimeoutError):
                self.failed += 1
                await asyncio.sleep(0.01)

    async def _ws(self) -> None:
        assert self._session is not None
        while True:
            try:
                async with self._session.ws_connect(self.url + "/api/ws") as ws:
                    while True:
                        await ws.send_str(json.dumps({"type": "twist", "source": "auto"}))
                        msg = await ws.receive(timeout=1)
                        if msg.type is not aiohttp.WSMsgType.TEXT:
                            break
                        self.ok += 1
                        await asyncio.sleep(0.02)
            except (aiohttp.ClientError, TimeoutError, ConnectionError):
                pass
            self.failed += 1
            await asyncio.sleep(0.01)


@contextlib.asynccontextmanager
async def driving(http: aiohttp.ClientSession, url: str) -> AsyncIterator[None]:
    """The HMI's drive pad held down: a manual twist every 100 ms."""

    async def stream() -> None:
        while True:
            with contextlib.suppress(aiohttp.ClientError):
                await post(http, url + "/api/base/twist", DRIVE)
            await asyncio.sleep(0.1)

    task = asyncio.create_task(stream())
    try:
        yield
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


async def start_motion(sim: Sim, http: aiohttp.ClientSession, url: str) -> None:
    """Torque on, two joints on slow sliders (seconds of motion); wait until all of it moves."""
    status, body = await post(http, url + "/api/arm/torque", {"enabled": True})
    assert (status, body) == (200, {"torque": "on"})
    for joint, angle in (("elbow_flex", 30.0), ("shoulder_lift", -25.0)):
        status, body = await post(
            http, url + f"/api/arm/joints/{joint}", {"angle_deg": angle, "speed_deg_s": 10.0}
        )
        assert status == 200, body
    expected = wheel_goals(sim)
    await wait_for(lambda: {w: sim.bus.servo(w).get("goal_speed") for w in WHEELS} == expected)
    await asyncio.sleep(0.3)


def assert_mid_motion(sim: Sim, before: float) -> None:
    """Both wheels energised at their drive speed, and the arm's goals streaming."""
    expected = wheel_goals(sim)
    assert {w: sim.bus.servo(w).get("goal_speed") for w in WHEELS} == expected
    assert all(sim.bus.servo(sid).torque for sid in ALL)
    recent = {w.id for w in sim.bus.writes_to(GOAL_POS, since=before - 0.1) if w.t < before}
    assert {ELBOW, LIFT} <= recent, f"the arm was not moving: goals went to {recent}"


def assert_all_limp_and_stopped(sim: Sim) -> None:
    assert [sim.bus.servo(w).get("goal_speed") for w in WHEELS] == [0, 0]
    on = [sid for sid in ALL if sim.bus.servo(sid).torque]
    assert on == [], f"still energised: {on}"


def describe(writes: list[WriteRecord]) -> list[str]:
    return [f"{w.t:.3f} id {w.id} @{w.address} {w.data.hex()}" for w in writes]


async def lupin_stop_helper(sim: Sim, home: Path) -> tuple[int, str]:
    proc = await asyncio.create_subprocess_exec(
        *lupin_cmd("stop-helper", "--bus-port", sim.path),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.STDOUT,
        env=child_env(home) | KILLED,
    )
    try:
        async with asyncio.timeout(10):
            out, _ = await proc.communicate()
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    assert proc.returncode is not None
    return proc.returncode, out.decode()


async def restart_and_prove_still(
    sim: Sim,
    http: aiohttp.ClientSession,
    home: Path,
    port: int,
    load: Load,
) -> DaemonProcess:
    """Start a new daemon on the same pty and port under load; prove it sends nothing.

    Returns it running; the caller stops it.
    """
    load.take()
    t_start = time.monotonic()
    proc = await MergedDaemonProcess.spawn(sim, home, port=port)
    try:
        await proc.ready()
        # The load is back on the new daemon: prove it by its counts, not by hope.
        load.take()
        await asyncio.sleep(1.0)
        ok, _ = load.take()
        assert ok > 50, f"the load did not reach the restarted daemon ({ok} answers)"
        # Refused, with a reason, until torque is set: a command that moves nothing.
        status, body = await post(
            http, proc.url + "/api/arm/joints/elbow_flex", {"angle_deg": 5.0, "speed_deg_s": 10}
        )
        assert status == 409, body
        written = sim.bus.writes(since=t_start)
        arm = [w for w in written if w.id in ARM]
        assert arm == [], f"the restarted daemon wrote to the arm: {describe(arm)}"
        wheel_on = [w for w in sim.bus.writes_to(TORQUE, since=t_start) if w.value("torque_enable")]
        assert wheel_on == [], f"the restarted daemon energised: {describe(wheel_on)}"
        state = await get_json(http, proc.url + "/api/state")
        assert all(j["status"] in ("idle", "settled") for j in state["joints"]), state["joints"]
    except BaseException:
        await proc.close()
        raise
    return proc


async def first_command_moves_without_a_jump(
    sim: Sim, http: aiohttp.ClientSession, url: str
) -> None:
    """Torque on, the operator's first command: each goal is seeded with the present position."""
    present = {sid: sim.bus.servo(sid).present_position for sid in ARM}
    t_cmd = time.monotonic()
    status, body = await post(http, url + "/api/arm/torque", {"enabled": True})
    assert (status, body) == (200, {"torque": "on"})
    for sid in ARM:
        goals = sim.bus.writes_to(GOAL_POS, since=t_cmd, id=sid)
        torque = [w for w in sim.bus.writes_to(TORQUE, since=t_cmd, id=sid)]
        assert goals and torque, f"servo {sid}: no seeded enable"
        assert goals[0].t <= torque[0].t
        first = goals[0].value("goal_position")
        assert first is not None and abs(first - present[sid]) <= 5, (sid, first, present[sid])


# -- the tests ------------------------------------------------------------------------------------


async def test_sigterm_mid_motion_under_load_zeroes_limps_and_exits_0_within_1s(
    sim: Sim, http: aiohttp.ClientSession, lupin_home: Path
) -> None:
    proc = await MergedDaemonProcess.spawn(sim, lupin_home)
    try:
        await proc.ready()
        async with Load(proc.url) as load, driving(http, proc.url):
            # A WebSocket client that never reads: the stop must not wait on it.
            stalled = await http.ws_connect(proc.url + "/api/ws")
            try:
                await start_motion(sim, http, proc.url)
                t_sig = time.monotonic()
                assert_mid_motion(sim, t_sig)
                assert load.take()[0] > 20, "the load is not hammering"
                proc.proc.send_signal(signal.SIGTERM)
                async with asyncio.timeout(1.0):
                    code = await proc.proc.wait()
                elapsed = time.monotonic() - t_sig
            finally:
                await stalled.close()
    finally:
        await proc.close()
    print(f"SIGTERM to exit: {elapsed:.3f} s")
    assert (code, elapsed < 1.0) == (0, True), (code, elapsed, proc.log)
    assert "Traceback" not in proc.log
    assert f"ready: so101 on {sim.path}, arm limp" in proc.log  # the bus it really owns

    # Judged at the servos: each wheel got a zero speed, then every servo a torque off...
    after = sim.bus.writes(since=t_sig)
    zero_at = {w.id: w.t for w in after if w.id in WHEELS and w.value("goal_speed") == 0}
    limp_at = {w.id: w.t for w in after if w.value("torque_enable") == 0}
    assert set(zero_at) == set(WHEELS), describe(after)
    assert set(limp_at) == set(ALL), describe(after)
    for wheel in WHEELS:
        assert zero_at[wheel] <= limp_at[wheel], "a wheel was limped before its speed was zeroed"
    # ...and nothing after the limp: no goal, no torque, for any servo.
    last_limp = max(limp_at.values())
    late = [w for w in after if w.t > last_limp]
    assert late == [], describe(late)
    assert_all_limp_and_stopped(sim)
    # Limp means still: the shafts stop where they are (no goal is being chased).
    resting = {sid: sim.bus.servo(sid).present_position for sid in ARM}
    await asyncio.sleep(0.2)
    sim.bus.advance(time.monotonic())
    assert all(abs(sim.bus.servo(s).present_position - resting[s]) <= 2 for s in (ELBOW, LIFT))


async def test_sigkill_mid_motion_then_stop_helper_then_restart_under_load(
    sim: Sim, http: aiohttp.ClientSession, lupin_home: Path
) -> None:
    port = free_port()
    proc = await MergedDaemonProcess.spawn(sim, lupin_home, port=port)
    try:
        await proc.ready()
        async with Load(proc.url) as load:
            async with driving(http, proc.url):
                await start_motion(sim, http, proc.url)
                t_kill = time.monotonic()
                assert_mid_motion(sim, t_kill)
                proc.proc.send_signal(signal.SIGKILL)
                async with asyncio.timeout(2):
                    assert await proc.proc.wait() == -signal.SIGKILL
            await proc.close()
            # Nobody limped anything: the base would still be driving.
            assert all(sim.bus.servo(sid).torque for sid in ALL)
            assert {w: sim.bus.servo(w).get("goal_speed") for w in WHEELS} == wheel_goals(sim)
            assert sim.all_writes(since=t_kill + 0.05) == []

            # systemd's ExecStopPost, while the clients keep knocking on the dead port.
            t_helper = time.monotonic()
            code, out = await lupin_stop_helper(sim, lupin_home)
            assert code == 0 and "limped" in out and "STILL ON" not in out, out
            assert_all_limp_and_stopped(sim)
            helper = sim.bus.writes(since=t_helper)
            assert {w.id for w in helper if w.value("torque_enable") == 0} == set(ALL)
            assert not [w for w in helper if w.value("torque_enable") or w.address == GOAL_POS]
            assert load.take()[1] > 0, "the load never noticed the daemon was gone"

            # Restart on the same pty and port, under the same load: nothing moves.
            second = await restart_and_prove_still(sim, http, lupin_home, port, load)
            try:
                state = await get_json(http, second.url + "/api/state")
                assert state["torque"] == "off" and state["mux"]["active"] in (None, "auto")
                await first_command_moves_without_a_jump(sim, http, second.url)
            finally:
                assert await second.stop() == 0
    finally:
        await proc.close()
    assert_all_limp_and_stopped(sim)


async def test_restart_under_load_after_a_clean_stop_moves_nothing_until_commanded(
    sim: Sim, http: aiohttp.ClientSession, lupin_home: Path
) -> None:
    port = free_port()
    first = await MergedDaemonProcess.spawn(sim, lupin_home, port=port)
    try:
        await first.ready()
        async with Load(first.url) as load:
            status, _ = await post(http, first.url + "/api/arm/torque", {"enabled": True})
            assert status == 200
            await asyncio.sleep(0.3)
            assert await first.stop() == 0
            assert_all_limp_and_stopped(sim)
            # A limp arm sags between the two runs; the new daemon must not put it back.
            for sid in ARM:
                sim.bus.servo(sid).move_by_hand(sim.bus.servo(sid).present_position - 120)
            second = await restart_and_prove_still(sim, http, lupin_home, port, load)
            try:
                await first_command_moves_without_a_jump(sim, http, second.url)
            finally:
                assert await second.stop() == 0
    finally:
        await first.close()


async def test_restart_after_an_uncleaned_sigkill_holds_the_arm_and_stops_the_wheels(
    sim: Sim, http: aiohttp.ClientSession, lupin_home: Path
) -> None:
    """No stop helper ran (by hand, or it failed): the arm is still energised, mid-trajectory,
    and the wheels still spin. The new daemon must not move the arm (no goal, no torque
    write; commands refused until an operator sets torque), and must stop the wheels."""
    port = free_port()
    proc = await MergedDaemonProcess.spawn(sim, lupin_home, port=port)
    try:
        await proc.ready()
        async with Load(proc.url) as load:
            async with driving(http, proc.url):
                await start_motion(sim, http, proc.url)
                assert_mid_motion(sim, time.monotonic())
                proc.proc.send_signal(signal.SIGKILL)
                async with asyncio.timeout(2):
                    await proc.proc.wait()
            await proc.close()
            spinning = {w: sim.bus.servo(w).get("goal_speed") for w in WHEELS}
            assert spinning == wheel_goals(sim) and all(spinning.values())
            held = {sid: sim.bus.servo(sid).get("goal_position") for sid in ARM}

            t_start = time.monotonic()
            second = await MergedDaemonProcess.spawn(sim, lupin_home, port=port)
            try:
                await second.ready()
                await asyncio.sleep(1.0)
                writes = sim.bus.writes(since=t_start)
                arm = [w for w in writes if w.id in ARM]
                assert arm == [], f"the restarted daemon wrote to the arm: {describe(arm)}"
                # The arm still holds exactly what the dead daemon last sent it.
                assert {sid: sim.bus.servo(sid).get("goal_position") for sid in ARM} == held
                assert all(sim.bus.servo(sid).torque for sid in ARM)
                # The wheels were stopped: zero speed, then limp.
                assert_wheels_stopped_at_start(sim, writes)
                state = await get_json(http, second.url + "/api/state")
                assert state["torque"] == "unknown", state["torque"]
                status, body = await post(
                    http, second.url + "/api/arm/joints/elbow_flex", {"angle_deg": 0.0}
                )
                assert status == 409, body
                assert "found ON at start-up" in second.log
                assert "stopping wheel" in second.log
                ok, _ = load.take()
                assert ok > 50
                # The operator takes over: torque on re-seeds from the measured pose.
                await first_command_moves_without_a_jump(sim, http, second.url)
            finally:
                assert await second.stop() == 0
    finally:
        await proc.close()
    assert_all_limp_and_stopped(sim)


def assert_wheels_stopped_at_start(sim: Sim, writes: list[WriteRecord]) -> None:
    zero = {w.id: w.t for w in writes if w.id in WHEELS and w.value("goal_speed") == 0}
    limp = {w.id: w.t for w in writes if w.id in WHEELS and w.value("torque_enable") == 0}
    assert set(zero) == set(WHEELS) and set(limp) == set(WHEELS), describe(writes)
    assert all(zero[w] <= limp[w] for w in WHEELS)
    assert all(not sim.bus.servo(w).torque for w in WHEELS)
    assert [sim.bus.servo(w).get("goal_speed") for w in WHEELS] == [0, 0]
    others = [w for w in writes if w.id in WHEELS and w.value("goal_speed") not in (0, None)]
    assert others == [], describe(others)


async def test_sigint_is_the_same_safe_stop(
    sim: Sim, http: aiohttp.ClientSession, lupin_home: Path
) -> None:
    """Ctrl-C on a bench run: the same sequence as SIGTERM (mid-motion, exit 0, < 1 s)."""
    proc = await MergedDaemonProcess.spawn(sim, lupin_home)
    try:
        await proc.ready()
        async with driving(http, proc.url):
            await start_motion(sim, http, proc.url)
            t_sig = time.monotonic()
            proc.proc.send_signal(signal.SIGINT)
            async with asyncio.timeout(1.0):
                assert await proc.proc.wait() == 0
        assert time.monotonic() - t_sig < 1.0
    finally:
        await proc.close()
    assert_all_limp_and_stopped(sim)
    assert sim.all_writes(since=t_sig + 0.5) == []
