"""Soak: ``lupin run`` in its own process for a bounded time, under everything at once.

For ``soak_seconds`` (default 120 s in CI; ``--soak-seconds N`` or
``LUPIN_SOAK_SECONDS=N`` for a long run) the daemon runs on the pty sim with, all
at once and at random (seeded; the seed is printed, ``LUPIN_SOAK_SEED=N`` replays
it):

* a recorded pad (``--pad replay:FILE``): dead-man drives, arm buttons, D-pad,
  triggers, the pad vanishing and coming back;
* an HMI on the WebSocket: drive-pad twists, sliders, gripper, presets, init;
* an autonomy stack posting ``auto`` twists over HTTP; HTTP sliders;
* an operator toggling torque and engaging/releasing the E-stop;
* bus faults: dropped, corrupted, cut, late and noisy replies on random servos,
  and a servo unplugged then plugged back.

Then it proves: no crash (the process lives, no traceback, no task restarted,
no ERROR line, no 5xx, health ok throughout), memory flat (RSS growth after
warm-up bounded), tick stable (rate near nominal, the last third's p99 period
not much worse than the first third's), and every state transition in the log:
E-stop, torque, mux source, servo lost/back, pad gone/back. Finally a SIGTERM
still stops everything safely.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import os
import random
import re
import time
from collections.abc import Awaitable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from lupintest.harness import Sim

from .helpers import (
    ALL,
    ARM,
    WHEELS,
    MergedDaemonProcess,
    period_buckets,
    scrape,
    tick_rate,
)

TICK_HZ = 100.0
NOMINAL = 1 / TICK_HZ
OVERHEAD_S = 5.0  # start-up, ready and the final stop, inside the soak's budget
MIN_RUN_S = 20.0
RSS_GROWTH_KIB = 10 * 1024
RSS_CEILING_KIB = 512 * 1024  # fail at once, long before a leak could hurt the machine
WARM_UP_S = 22.0
# Xbox over Bluetooth (config/pads/xbox-bluetooth.yaml).
LB, RB = 6, 7
ARM_BUTTONS = (0, 1, 3, 4, 10, 11)  # shoulder lift/pan on the face buttons, wrist roll
DPAD = (6, 7)  # wrist, elbow axes
RT, LT = 4, 5  # triggers: rest at +1, full pull at -1


@dataclass
class Tally:
    """What the soak did and saw, to judge the daemon's log and answers by."""

    estop_engaged: int = 0
    estop_released: int = 0
    torque_enables: int = 0  # answered "on" from "off"
    torque_disables: int = 0
    kills: dict[int, int] = field(default_factory=dict)  # id -> times unplugged
    faults: list[str] = field(default_factory=list)
    statuses: dict[int, int] = field(default_factory=dict)
    ws_replies: dict[str, int] = field(default_factory=dict)
    bad: list[str] = field(default_factory=list)  # 5xx answers, internal errors
    mux_seen: set[str] = field(default_factory=set)
    health_not_ok: int = 0
    rss: list[tuple[float, int]] = field(default_factory=list)
    scrapes: list[tuple[float, dict[str, float]]] = field(default_factory=list)

    def status(self, code: int, what: str) -> None:
        self.statuses[code] = self.statuses.get(code, 0) + 1
        if code >= 500:
            self.bad.append(f"{what}: HTTP {code}")


# -- the pad recording ------------------------------------------------------------------------


def pad_frame(
    t: float,
    *,
    lb: bool = False,
    rb: bool = False,
    fwd: float = 0.0,
    yaw: float = 0.0,
    button: int | None = None,
    dpad: tuple[int, float] | None = None,
    trigger: tuple[int, float] | None = None,
) -> dict[str, Any]:
    axes = [0.0, fwd, yaw, 0.0, 1.0, 1.0, 0.0, 0.0]
    if dpad is not None:
        axes[dpad[0]] = dpad[1]
    if trigger is not None:
        axes[trigger[0]] = trigger[1]
    buttons = [0] * 15
    for b in (LB if lb else None, RB if rb else None, button):
        if b is not None:
            buttons[b] = 1
    return {"t": round(t, 3), "axes": axes, "buttons": buttons}


def pad_recording(rng: random.Random, seconds: float) -> list[dict[str, Any]]:
    """Random episodes at 10 frames/s: drive under the dead-man, arm controls, idle, vanish."""
    out: list[dict[str, Any]] = []
    t = 0.0
    while t < seconds:
        kind = rng.choices(["drive", "arm", "idle", "vanish"], [4, 3, 3, 0.5])[0]
        length = rng.uniform(0.5, 2.5)
        end = t + length
        if kind == "vanish":
            out.append({"t": round(t, 3), "event": "disconnect"})
            t = end
            out.append({"t": round(t, 3), "event": "connect"})
            continue
        held: dict[str, Any] = {}
        if kind == "drive":
            held = {"lb": True, "rb": rng.random() < 0.2}
            held |= {"fwd": rng.uniform(-1, 1), "yaw": rng.uniform(-1, 1)}
        elif kind == "arm":
            held = rng.choice(
                [
                    {"button": rng.choice(ARM_BUTTONS)},
                    {"dpad": (rng.choice(DPAD), rng.choice((-1.0, 1.0)))},
                    {"trigger": (rng.choice((RT, LT)), rng.uniform(-1.0, 0.5))},
                ]
            )
        while t < end:
            out.append(pad_frame(t, **held))
            t += 0.1
        out.append(pad_frame(t))  # everything released between episodes
        t += 0.1
    return out


# -- the clients --------------------------------------------------------------------------------


@dataclass
class Soak:
    url: str
    sim: Sim
    seed: int
    tally: Tally
    robot: dict[str, Any]
    deadline: float
    torque: str = "off"  # as last answered by the daemon

    def running(self) -> bool:
        return time.monotonic() < self.deadline

    def rng(self, client: str) -> random.Random:
        """Each client its own stream: the same seed makes the same choices, whatever the
        interleaving of the clients."""
        return random.Random(f"{self.seed}:{client}")

    async def pause(self, rng: random.Random, lo: float, hi: float) -> None:
        """A random pause, cut short at the deadline (the E-stop is still released)."""
        left = self.deadline - time.monotonic()
        await asyncio.sleep(max(0.0, min(rng.uniform(lo, hi), left)))

    def joint_target(self, rng: random.Random) -> tuple[str, float]:
        joints = [j for j in self.robot["joints"] if not j["is_gripper"]]
        joint = rng.choice(joints)
        lo, hi = joint["window_deg"]
        return joint["name"], rng.uniform(0.8 * lo, 0.8 * hi)

    async def call(
        self, http: aiohttp.ClientSession, method: str, path: str, body: Any = None
    ) -> tuple[int, Any]:
        async with http.request(method, self.url + path, json=body) as resp:
            data = await resp.json(content_type=None)
            self.tally.status(resp.status, f"{method} {path}")
            return resp.status, data

    # Each client runs until the deadline; a client that raises fails the soak.

    async def autonomy(self, http: aiohttp.ClientSession) -> None:
        rng = self.rng("autonomy")
        while self.running():
            twist = {
                "source": "auto",
                "linear_x": rng.uniform(-0.2, 0.2),
                "angular_z": rng.uniform(-0.8, 0.8),
            }
            for _ in range(rng.randint(5, 30)):
                if not self.running():
                    break
                await self.call(http, "POST", "/api/base/twist", twist)
                await asyncio.sleep(0.1)
            await self.pause(rng, 0.3, 3.0)

    async def sliders(self, http: aiohttp.ClientSession) -> None:
        rng = self.rng("sliders")
        while self.running():
            if rng.random() < 0.8:
                joint, angle = self.joint_target(rng)
                body = {"angle_deg": angle, "speed_deg_s": rng.uniform(10, 90)}
                await self.call(http, "POST", f"/api/arm/joints/{joint}", body)
            else:
                grip = self.robot["gripper"]
                lo, hi = sorted((grip["hmi_open_deg"], grip["hmi_closed_deg"]))
                body = {"angle_deg": rng.uniform(lo, hi)}
                await self.call(http, "POST", "/api/arm/gripper", body)
            await self.pause(rng, 0.2, 1.5)

    async def operator(self, http: aiohttp.ClientSession) -> None:
        """Torque on most of the time, sometimes off; the E-stop now and then."""
        rng = self.rng("operator")
        await self.pause(rng, 0.5, 1.5)
        n = 0
        while self.running():
            n += 1  # torque on first, then an E-stop, then at random
            if n == 2 or (n > 2 and rng.random() < 0.3):
                status, _ = await self.call(http, "POST", "/api/estop", {"engaged": True})
                assert status == 200
                self.tally.estop_engaged += 1
                await self.pause(rng, 0.3, 1.5)
                status, _ = await self.call(http, "POST", "/api/estop", {"engaged": False})
                assert status == 200
                self.tally.estop_released += 1
            elif self.torque != "on":
                status, data = await self.call(http, "POST", "/api/arm/torque", {"enabled": True})
                assert status == 200, data
                if self.torque == "off" and data["torque"] == "on":
                    self.tally.torque_enables += 1  # a transition that must be in the log
                self.torque = data["torque"]
            elif rng.random() < 0.4:  # mostly left on: the sliders and the pad need it
                status, data = await self.call(http, "POST", "/api/arm/torque", {"enabled": False})
                assert status == 200, data
                self.tally.torque_disables += 1
                self.torque = data["torque"]
            await self.pause(rng, 1.5, 4.0)

    async def hmi(self, http: aiohttp.ClientSession) -> None:
        """The browser HMI: drive-pad twists at 10 Hz, and commands answered by id."""
        rng = self.rng("hmi")
        n = 0
        while self.running():
            async with http.ws_connect(self.url + "/api/ws") as ws:
                reader = asyncio.create_task(self._hmi_read(ws))
                try:
                    while self.running():
                        n += 1
                        if rng.random() < 0.5:
                            twist = {
                                "type": "twist",
                                "source": "manual",
                                "linear_x": rng.uniform(-0.2, 0.2),
                                "angular_z": rng.uniform(-1.0, 1.0),
                            }
                            for _ in range(rng.randint(3, 20)):
                                if not self.running():
                                    break
                                await ws.send_str(json.dumps(twist))
                                await asyncio.sleep(0.1)
                        else:
                            await ws.send_str(json.dumps(self._command(rng, n)))
                        await self.pause(rng, 0.1, 1.0)
                finally:
                    reader.cancel()
                    with contextlib.suppress(asyncio.CancelledError):
                        await reader
            if self.running():
                self.tally.bad.append("the server closed the HMI's WebSocket")

    def _command(self, rng: random.Random, n: int) -> dict[str, Any]:
        kind = rng.choices(["joint", "gripper", "preset", "init"], [6, 2, 2, 1])[0]
        frame: dict[str, Any] = {"type": kind, "id": n}
        if kind == "joint":
            frame["joint"], frame["angle_deg"] = self.joint_target(rng)
            frame["speed_deg_s"] = rng.uniform(10, 90)
        elif kind == "gripper":
            grip = self.robot["gripper"]
            frame["angle_deg"] = grip["hmi_open_deg"]
        elif kind == "preset":
            frame["name"] = rng.choice(sorted(self.robot["presets"]))
        return frame

    async def _hmi_read(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        async for msg in ws:
            data = json.loads(msg.data)
            if data["type"] == "reply":
                code = "ok" if data["ok"] else data["error"]["code"]
                self.tally.ws_replies[code] = self.tally.ws_replies.get(code, 0) + 1
                if code in ("internal", "invalid_frame"):
                    self.tally.bad.append(f"WebSocket reply {data}")
            elif data["type"] == "error":
                self.tally.bad.append(f"WebSocket error frame {data}")

    async def faults(self, t0: float, third: float) -> None:
        """Bus faults, one at a time: bursts of bad replies, a servo unplugged then back.

        One random plan, played in each third of the run, so the thirds see the same
        faults and their tick jitter can be compared: a change is then the daemon's.
        """
        rng = self.rng("faults")
        kinds = ["drop", "corrupt", "truncate", "delay", "garbage", "unplug"]
        plan: list[tuple[float, float, str, list[int], float, dict[str, float]]] = []
        at = rng.uniform(1.0, 2.0)
        while at < third - 1.0:
            kind = rng.choice(kinds)
            # An unplug outlasts the 10 missed reads (0.1 s) that count a servo as lost.
            length = min(
                rng.uniform(0.3, 1.5) if kind == "unplug" else rng.uniform(0.5, 3.0),
                third - 0.3 - at,
            )
            ids = [rng.choice(ALL)] if kind == "unplug" else rng.sample(ALL, rng.randint(1, 3))
            if kind != "unplug" and rng.random() < 0.3:
                ids = list(ALL)
            rate = rng.uniform(0.02, 0.2)
            extra = {"seconds": rng.uniform(0.002, 0.006)} if kind == "delay" else {}
            plan.append((at, length, kind, ids, rate, extra))
            at += length + rng.uniform(0.5, 3.0)
        for k in range(3):
            for at, length, kind, ids, rate, extra in plan:
                await asyncio.sleep(max(0.0, t0 + k * third + at - time.monotonic()))
                if kind == "unplug":
                    self.sim.bus.kill(ids[0])
                    self.tally.kills[ids[0]] = self.tally.kills.get(ids[0], 0) + 1
                else:
                    self.sim.bus.inject(kind, ids=ids, rate=rate, **extra)  # type: ignore[arg-type]
                self.tally.faults.append(f"{kind} {ids} {rate:.2f} {length:.1f} s")
                try:
                    await asyncio.sleep(length)
                finally:
                    self.sim.bus.clear_faults()
                    for sid in ids:
                        self.sim.bus.revive(sid)

    async def monitor(
        self, http: aiohttp.ClientSession, proc: MergedDaemonProcess, marks: list[float]
    ) -> None:
        """Every 0.25 s: alive, healthy, mux source; every 1 s RSS; /metrics at each mark."""
        marks = sorted(marks)
        n = 0
        while self.running():
            assert proc.proc.returncode is None, f"the daemon died:\n{proc.log[-4000:]}"
            async with http.get(self.url + "/api/state") as resp:
                self.tally.status(resp.status, "GET /api/state")
                state = await resp.json()
            self.tally.mux_seen.add(state["mux"]["active"] or "nothing")
            if n % 4 == 0:
                async with http.get(self.url + "/api/health") as resp:
                    self.tally.status(resp.status, "GET /api/health")
                    self.tally.health_not_ok += not (await resp.json())["ok"]
                rss = proc.rss_kib()
                self.tally.rss.append((time.monotonic(), rss))
                assert rss < RSS_CEILING_KIB, f"the daemon's RSS reached {rss} KiB"
            while marks and time.monotonic() >= marks[0]:
                marks.pop(0)
                self.tally.scrapes.append((time.monotonic(), await scrape(http, self.url)))
            n += 1
            await asyncio.sleep(0.25)


# -- judging ----------------------------------------------------------------------------------


def p99_period(before: dict[str, float], after: dict[str, float]) -> float:
    """The tick period's 99th percentile between two scrapes, to histogram resolution."""
    b, a = period_buckets(before), period_buckets(after)
    inf = float("inf")
    total = a[inf] - b.get(inf, 0.0)
    assert total > 0
    for bound in sorted(a):
        if (a[bound] - b.get(bound, 0.0)) / total >= 0.99:
            return bound
    return inf


def connection_edges(frames: list[dict[str, Any]], until: float) -> dict[str, int]:
    """How often the recorded pad comes (a frame after silence) and goes, before ``until``."""
    edges = {"connected": 0, "gone": 0}
    connected = False
    for entry in frames:
        if entry["t"] >= until:
            break
        now = entry.get("event") != "disconnect" and "axes" in entry
        if entry.get("event") == "connect":
            continue  # the next frame is what connects it
        if now != connected:
            edges["connected" if now else "gone"] += 1
            connected = now
    return edges


def log_count(log: str, pattern: str) -> int:
    return len(re.findall(pattern, log))


def mux_chain(log: str) -> list[tuple[str, str]]:
    """(was, now) of every mux line, in order."""
    return [(m[1], m[0]) for m in re.findall(r"mux: (\w+) drives the base \(was (\w+)\)", log)]


@pytest.fixture()
def soak_budget(request: pytest.FixtureRequest, soak_seconds: float) -> float:
    """The soak's own time limit replaces the suite's per-test timeout (a long soak by flag)."""
    request.node.add_marker(pytest.mark.timeout(soak_seconds + 60, func_only=True), append=False)
    return soak_seconds


@pytest.mark.timeout(180, func_only=True)
async def test_soak(sim: Sim, lupin_home: Path, tmp_path: Path, soak_budget: float) -> None:
    seed = int(os.environ.get("LUPIN_SOAK_SEED") or random.SystemRandom().randrange(2**32))
    print(f"soak seed {seed} (replay with LUPIN_SOAK_SEED={seed})")
    sim.bus.rng.seed(seed)
    run_s = max(MIN_RUN_S, soak_budget - OVERHEAD_S)
    pad = tmp_path / "soak-pad.jsonl"
    frames = pad_recording(random.Random(f"{seed}:pad"), run_s + 2)
    pad.write_text("".join(json.dumps(f) + "\n" for f in frames))
    pad_edges = connection_edges(frames, until=run_s - 0.5)

    proc = await MergedDaemonProcess.spawn(
        sim, lupin_home, "--pad", f"replay:{pad}", "--pad-layout", "xbox-bluetooth"
    )
    tally = Tally()
    try:
        await proc.ready()
        async with aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=5)) as http:
            async with http.get(proc.url + "/api/robot") as resp:
                robot = await resp.json()
            t0 = time.monotonic()
            soak = Soak(proc.url, sim, seed, tally, robot, deadline=t0 + run_s)
            # The tick keeps its last 2000 periods (20 s): memory is judged once they are full.
            warm = t0 + min(max(run_s / 3, WARM_UP_S), run_s / 2)
            third = run_s / 3
            marks = [t0 + 0.2, t0 + third, t0 + 2 * third]
            clients: list[Awaitable[None]] = [
                soak.autonomy(http),
                soak.sliders(http),
                soak.operator(http),
                soak.hmi(http),
                soak.faults(t0, run_s / 3),
                soak.monitor(http, proc, marks),
            ]
            async with asyncio.timeout(run_s + 30):
                await asyncio.gather(*clients)
            tally.scrapes.append((time.monotonic(), await scrape(http, proc.url)))
            sim.bus.clear_faults()
            for sid in ALL:
                sim.bus.revive(sid)
            await asyncio.sleep(0.6)  # the last twists time out
            alive = proc.proc.returncode is None
            final = await scrape(http, proc.url)
        t_stop = time.monotonic()
        code = await proc.stop()
    finally:
        await proc.close()
    log = proc.log
    context = f"seed {seed}; faults {tally.faults}"

    (ta, a), (_, b), (_, c), (td, d) = tally.scrapes
    hz = tick_rate(a, d, td - ta)
    first, last = p99_period(a, b), p99_period(c, d)
    print(
        f"soak: {run_s:.0f} s; tick {hz:.1f} Hz, p99 period {first * 1e3:.1f} ms first third, "
        f"{last * 1e3:.1f} ms last; HTTP {tally.statuses}; WebSocket replies "
        f"{tally.ws_replies}; E-stops {tally.estop_engaged}; torque on {tally.torque_enables} "
        f"off {tally.torque_disables}; unplugged {tally.kills}; {len(tally.faults)} faults; "
        f"mux seen {sorted(tally.mux_seen)}; RSS KiB {tally.rss[0][1]} .. {tally.rss[-1][1]}"
    )

    # -- zero crashes --------------------------------------------------------------------
    assert alive and code == 0, (code, context, log[-4000:])
    for needle in ("Traceback", "crashed; restarting", "control tick failed"):
        assert needle not in log, (needle, context)
    loud = [line for line in proc.lines if re.search(r" (ERROR|CRITICAL) ", line)]
    assert loud == [], (loud, context)
    assert tally.bad == [], (tally.bad[:10], context)
    assert tally.health_not_ok == 0
    assert sum(tally.statuses.values()) > 10 * run_s, tally.statuses  # the clients were busy
    assert sum(tally.ws_replies.values()) > 0 and tally.statuses.get(200, 0) > 0

    # -- memory flat after warm-up --------------------------------------------------------------
    after_warm = [kib for t, kib in tally.rss if t >= warm]
    assert len(after_warm) >= 5, tally.rss
    growth = max(after_warm) - after_warm[0]
    assert growth < RSS_GROWTH_KIB, f"RSS grew {growth} KiB after warm-up: {tally.rss}"

    # -- the tick: near its rate, and the last third no worse than the first ----------------------
    assert hz >= 0.9 * TICK_HZ, f"the tick ran at {hz:.1f} Hz ({context})"
    assert last <= max(2 * first, 2 * NOMINAL), (
        f"p99 tick period {first * 1e3:.1f} ms in the first third, {last * 1e3:.1f} ms in the "
        f"last ({context})"
    )
    assert final["lupin_ticks_total"] > d["lupin_ticks_total"]

    # -- every state transition is in the log -----------------------------------------------------
    assert log_count(log, r"E-stop ENGAGED") == tally.estop_engaged
    assert log_count(log, r"E-stop released") == tally.estop_released
    assert tally.estop_engaged > 0
    assert log_count(log, r"arm torque on; command gate open") >= max(tally.torque_enables, 1)
    assert log_count(log, r"arm torque off; command gate closed") == tally.torque_disables
    chain = mux_chain(log)
    for (_, now), (was, _) in itertools.pairwise(chain):
        assert was == now, f"mux lines out of step: {chain}"
    logged_sources = {now for _, now in chain} | {was for was, _ in chain}
    assert tally.mux_seen <= logged_sources, (tally.mux_seen, logged_sources)
    assert {"joy", "manual", "auto"} <= logged_sources, logged_sources
    for sid, kills in tally.kills.items():
        lost = log_count(log, rf"\(id {sid}\) not answering")
        back = log_count(log, rf"\(id {sid}\) answering again")
        assert lost >= kills and back >= kills, (sid, kills, lost, back, context)
        if sid in WHEELS:
            assert "base will not drive" in log
    assert log_count(log, r"pad replay:\S+: connected") >= pad_edges["connected"] > 0
    assert log_count(log, r"pad replay:\S+: gone") >= pad_edges["gone"]

    # -- and it still stops safely -------------------------------------------------------------
    after = sim.bus.writes(since=t_stop)
    assert {w.id for w in after if w.value("torque_enable") == 0} == set(ALL)
    assert [sim.bus.servo(w).get("goal_speed") for w in WHEELS] == [0, 0]
    assert not any(sim.bus.servo(sid).torque for sid in ARM + WHEELS)
