"""Latency benchmark: pad and E-stop to the simulated servos, with the daemon in this process.

Prints one JSON document (and writes ``bench/results/latency.json``):

* **stop**: dead-man release (a pad frame with LB up) -> both wheels' goal speed 0
  received by the simulated servos;
* **estop_http** / **estop_ws**: ``POST /api/estop`` / the WebSocket frame
  ``{"type": "estop", "engaged": true, "id": N}`` sent -> both wheels at goal speed 0;
* **teleop**: a stick change with LB held -> the new goal speed received;
* **wire**: bytes on the bus per tick, idle and while driving, from the daemon's
  own bus counters, next to the codec's figures.

Latencies are given in milliseconds and in ticks (latency / tick period). The
"one tick" target is reported two ways, both counted per sample:

* ``next_tick_write``: the goal went out in the tick that was running at the
  stimulus or in the next one, i.e. the servos saw at most one SYNC_READ (a tick
  start) between stimulus and goal. Such a goal can still land a little over one
  period after the stimulus (a stimulus just after a tick's write waits for the
  next tick's read before its write);
* ``under_one_period``: the latency was shorter than one tick period in ms.

    python bench/latency.py                 # 200 releases, 100 E-stops each way
    python bench/latency.py --smoke         # tiny counts, for the test suite
"""

from __future__ import annotations

import asyncio
import random
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

import aiohttp
from benchlib import output, stats
from benchlib.rig import Rig, rig
from benchlib.ws_client import WsClient

from lupin import control_table as ct
from lupin import protocol
from lupin.bus import BITS_PER_BYTE, STATUS_OVERHEAD
from lupin.control_loop import HEALTH_LEN, STATE_ADDR, STATE_LEN
from lupin.logs import setup_logging

NAME = "latency"
T = TypeVar("T")
SETTLE = (0.025, 0.04)  # s after a stimulus before its goal is looked up (latency <= ~15 ms)
POLL = 0.01  # s between looks for a goal not in yet
MISS_AFTER = 5.0  # s after the stimulus: a goal not at the servos by then never came
GAP = (0.005, 0.02)  # s of random spacing, so stimuli land at every phase of the tick

METHOD = (
    "One process, one event loop, one clock (time.monotonic): the so101 simulator "
    "(PtySimServer on a pty, replies paced at 1 Mbaud) and the real Daemon (bus over "
    "pyserial-asyncio on that pty, 100 Hz tick, arm limp, no auto-home) with its ApiServer "
    "on 127.0.0.1 and its pad task (lupin.pad_task.run_pad with BaseTeleop/ArmTeleop and "
    "the xbox-bluetooth mapping, wired as Daemon.prepare_pad wires it) reading an in-memory "
    "PadFeed. A WebSocket client stays connected throughout (state frames at 20 Hz, as with "
    "the HMI open). The start of each latency is time.monotonic() when the frame is handed "
    "to the pad reader's queue (pad), just before session.post (HTTP) or ws.send_str (WS); "
    "its end is the simulator's receive stamp of the first SYNC_WRITE carrying the expected "
    "goal speed (0 for both wheels, or the left wheel's new value): time.monotonic() when "
    "the simulator's pty reader decoded the packet, i.e. when the daemon's write reached the "
    "pty, with no wire time added or taken off (on a real 1 Mbaud line the packet's last "
    "byte would land its own wire time later: 10 us a byte, 0.14 ms for the 14-byte "
    "two-wheel goal-speed SYNC_WRITE). A goal not found is looked for again every 10 ms up "
    "to 5 s after the stimulus before it counts as missed, so a busy machine delays a "
    "sample rather than dropping it. Stimuli are spaced by random gaps so they fall at "
    "every phase of the tick. Each cycle: LB down "
    "(neutral), stick to v1, stick to v2 (two teleop samples), LB up (one stop sample); "
    "E-stop cycles drive with LB+stick, engage, then release the pad and the E-stop."
)
WIRE_METHOD = (
    "Daemon's ServoBus.stats.bytes_out + bytes_in over the window divided by "
    "ControlLoop.stats.ticks over it; idle = no command, driving = the pad streaming a new "
    "stick value every 10 ms (a wheel goal SYNC_WRITE nearly every tick). Wire time at 10 "
    "bits a byte; utilisation is a fraction (1.0 = the line never idle) at the tick rate. "
    "Codec figures (computed from packet sizes, not measured): one full-state SYNC_READ of "
    "every servo with its replies, the round-robin health READ (1 in "
    "control.health_every_ticks ticks), and the largest "
    "goal write (goal position + speed, 6 bytes, to every servo)."
)


@dataclass
class Sample:
    latency_s: float
    ticks_started: int
    reply_s: float | None = None  # request -> HTTP response / WebSocket reply


@dataclass
class Samples:
    items: list[Sample] = field(default_factory=list)
    missed: int = 0

    def summary(self, period: float) -> dict[str, Any]:
        """The figures, with the "one tick" target counted both ways (see the module doc)."""
        lat = [s.latency_s for s in self.items]
        ticks = [s.ticks_started for s in self.items]
        replies = [s.reply_s for s in self.items if s.reply_s is not None]
        under = sum(1 for v in lat if v < period)
        out: dict[str, Any] = {
            "latency_ms": stats.ms(lat),
            "latency_ticks": stats.summary([v / period for v in lat]),
            "ticks_started_max": max(ticks, default=None),
            "next_tick_write": sum(1 for t in ticks if t <= 1),
            "under_one_period": under,
            "under_one_period_fraction": round(under / len(lat), 4) if lat else None,
            "period_ms": round(1000 * period, 3),
            "missed": self.missed,
        }
        if replies:
            out["reply_ms"] = stats.ms(replies)
        return out


def first_stop(rig_: Rig, since: float) -> float | None:
    """When every wheel's goal speed had been set to 0 by writes received after ``since``."""
    latest: dict[int, int] = {}
    for t, sid, value in sorted(rig_.wheel_goals(since)):
        latest[sid] = value
        if len(latest) == len(rig_.wheel_ids) and not any(latest.values()):
            return t
    return None


def first_change(rig_: Rig, since: float, before: int) -> tuple[float, int] | None:
    """The first left-wheel goal speed other than ``before`` received after ``since``."""
    left = rig_.wheel_ids[0]
    for t, sid, value in sorted(rig_.wheel_goals(since)):
        if sid == left and value != before:
            return t, value
    return None


async def settle(rng: random.Random) -> None:
    await asyncio.sleep(rng.uniform(*SETTLE))


async def look_up(
    rng: random.Random, since: float, find: Callable[..., T | None], *args: Any
) -> T | None:
    """``find(*args)`` after the settle time, then every ``POLL`` until ``MISS_AFTER``.

    The latency comes from the stamps, not from when it is looked up, so waiting
    longer costs nothing when the goal is in; a fixed short wait would count a
    goal delayed by a busy machine as missed.
    """
    await settle(rng)
    found = find(*args)
    while found is None and time.monotonic() - since < MISS_AFTER:
        await asyncio.sleep(POLL)
        found = find(*args)
    return found


async def gap(rng: random.Random) -> None:
    await asyncio.sleep(rng.uniform(*GAP))


def stick(rng: random.Random) -> float:
    """A deflection well past the 0.15 deadzone, either way."""
    return rng.choice((-1, 1)) * rng.uniform(0.4, 1.0)


async def pad_cycles(rig_: Rig, n: int, rng: random.Random) -> tuple[Samples, Samples]:
    """``n`` dead-man releases, each after two stick changes: (teleop, stop) samples."""
    teleop, stop = Samples(), Samples()
    left = 0
    for _ in range(n):
        rig_.pad.put(lb=True)  # a fresh press with the stick neutral arms the dead-man
        await gap(rng)
        v1 = stick(rng)
        for v in (v1, v1 * rng.uniform(0.5, 0.8)):
            t0 = rig_.pad.put(lb=True, fwd=v)
            found = await look_up(rng, t0, first_change, rig_, t0, left)
            if found is None:
                teleop.missed += 1
                continue
            t, left = found
            teleop.items.append(Sample(t - t0, rig_.sync_reads(t0, t)))
        t0 = rig_.pad.put(lb=False)
        t_stop = await look_up(rng, t0, first_stop, rig_, t0)
        if t_stop is None:
            stop.missed += 1
        else:
            stop.items.append(Sample(t_stop - t0, rig_.sync_reads(t0, t_stop)))
            left = 0
        await gap(rng)
    return teleop, stop


async def estop_cycles(
    rig_: Rig, n: int, rng: random.Random, engage: Callable[[bool], Awaitable[None]]
) -> Samples:
    """Drive with the pad, E-stop through ``engage``, then release pad and E-stop; ``n`` times."""
    out = Samples()
    for _ in range(n):
        rig_.pad.put(lb=True)
        await gap(rng)
        t_drive = rig_.pad.put(lb=True, fwd=stick(rng))
        if await look_up(rng, t_drive, first_change, rig_, t_drive, 0) is None:
            out.missed += 1  # never moved: nothing to stop
        else:
            t0 = time.monotonic()
            await engage(True)
            reply = time.monotonic() - t0
            t_stop = await look_up(rng, t0, first_stop, rig_, t0)
            if t_stop is None:
                out.missed += 1
            else:
                out.items.append(Sample(t_stop - t0, rig_.sync_reads(t0, t_stop), reply))
        rig_.pad.put(lb=False)
        await gap(rng)
        await engage(False)
        await gap(rng)
    return out


async def wire_window(rig_: Rig, seconds: float, drive: bool) -> dict[str, Any]:
    """Bytes on the bus per tick over ``seconds``, from the daemon's own counters."""
    bus, loop = rig_.daemon.bus, rig_.daemon.loop
    assert bus is not None and loop is not None
    if drive:
        rig_.pad.put(lb=False)  # a fresh press arms the dead-man
        rig_.pad.put(lb=True)
        await asyncio.sleep(0.05)
    out0, in0, ticks0 = bus.stats.bytes_out, bus.stats.bytes_in, loop.stats.ticks
    writes0 = loop.stats.writes
    deadline = time.monotonic() + seconds
    step = 0
    while time.monotonic() < deadline:
        if drive:
            step += 1
            rig_.pad.put(lb=True, fwd=0.4 + 0.5 * ((step % 50) / 50))
        await asyncio.sleep(0.01)
    ticks = loop.stats.ticks - ticks0
    b_out, b_in = bus.stats.bytes_out - out0, bus.stats.bytes_in - in0
    if drive:
        rig_.pad.put(lb=False)
        await asyncio.sleep(0.05)
    per_tick = (b_out + b_in) / ticks
    baud = rig_.profile.bus.baud
    return {
        "ticks": ticks,
        "goal_writes_per_tick": round((loop.stats.writes - writes0) / ticks, 3),
        "bytes_out_per_tick": round(b_out / ticks, 2),
        "bytes_in_per_tick": round(b_in / ticks, 2),
        "bytes_per_tick": round(per_tick, 2),
        "wire_ms_per_tick": round(1000 * per_tick * BITS_PER_BYTE / baud, 4),
        "utilisation_fraction_at_tick_hz": round(
            per_tick * BITS_PER_BYTE / baud * rig_.profile.control.tick_hz, 4
        ),
    }


def codec_tick(rig_: Rig) -> dict[str, Any]:
    """Bytes per tick computed from the codec: what the wire must carry, whoever measures it.

    Packet sizes only, nothing timed: the table labels this baseline "computed".
    """
    ids = rig_.daemon.loop.ids if rig_.daemon.loop else []
    request = len(protocol.sync_read(STATE_ADDR, STATE_LEN, ids))
    replies = len(ids) * (STATUS_OVERHEAD + STATE_LEN)
    health_every = rig_.profile.control.health_every_ticks
    health = (
        len(protocol.read(ids[0], ct.REGISTERS["present_voltage"].address, HEALTH_LEN))
        + STATUS_OVERHEAD
        + HEALTH_LEN
    ) / health_every
    goal = ct.REGISTERS["goal_position"].address
    worst_goal = len(protocol.sync_write(goal, 6, {i: bytes(6) for i in ids}))
    idle = request + replies + health
    busiest = idle + worst_goal
    baud, hz = rig_.profile.bus.baud, rig_.profile.control.tick_hz
    return {
        "sync_read_request": request,
        "sync_read_replies": replies,
        "health_read_per_tick": round(health, 2),
        "largest_goal_write": worst_goal,
        "idle_bytes_per_tick": round(idle, 2),
        "busiest_bytes_per_tick": round(busiest, 2),
        "idle_utilisation_fraction_at_tick_hz": round(idle * BITS_PER_BYTE / baud * hz, 4),
        "busiest_utilisation_fraction_at_tick_hz": round(busiest * BITS_PER_BYTE / baud * hz, 4),
        "max_tick_hz_busiest": round(baud / (busiest * BITS_PER_BYTE), 1),
    }


def tick_periods(rig_: Rig) -> dict[str, Any]:
    loop = rig_.daemon.loop
    assert loop is not None
    nominal = rig_.tick_period
    return {
        "period_ms": stats.ms(list(loop.stats.periods)),
        "jitter_ms": stats.ms([abs(p - nominal) for p in loop.stats.periods]),
        "overruns": loop.stats.overruns,
        "ticks": loop.stats.ticks,
    }


async def run(releases: int, estops: int, wire_s: float, seed: int) -> dict[str, Any]:
    rng = random.Random(seed)
    async with rig() as r, aiohttp.ClientSession() as session:
        ws = await WsClient.connect(session, r.url)
        try:
            wire_idle = await wire_window(r, wire_s, drive=False)
            wire_drive = await wire_window(r, wire_s, drive=True)
            teleop, stop = await pad_cycles(r, releases, rng)

            async def http(engaged: bool) -> None:
                url = f"{r.url}/api/estop"
                async with session.post(url, json={"engaged": engaged}) as response:
                    response.raise_for_status()
                    await response.read()

            async def websocket(engaged: bool) -> None:
                reply = await ws.request({"type": "estop", "engaged": engaged})
                if not reply.get("ok"):
                    raise RuntimeError(f"E-stop refused over the WebSocket: {reply}")

            estop_http = await estop_cycles(r, estops, rng, http)
            estop_ws = await estop_cycles(r, estops, rng, websocket)
            periods = tick_periods(r)
            states = ws.states
        finally:
            await ws.close()
        period = r.tick_period
        codec = codec_tick(r)
        tick_hz = r.profile.control.tick_hz
    return {
        "benchmark": NAME,
        "config": {
            **output.machine(),
            "profile": "so101",
            "tick_hz": tick_hz,
            "wire_pacing": True,
            "simulator": "in this process: PtySimServer on a pty, same event loop",
            "pad_layout": "xbox-bluetooth",
            "releases": releases,
            "estops_per_channel": estops,
            "seed": seed,
            "ws_states_received": states,
        },
        "method": METHOD,
        "target": "one tick (one period): next_tick_write counts goals that went out in the "
        "tick running at the stimulus or the next one (ticks_started <= 1; such a goal can "
        "land up to one period plus a tick's read and write after the stimulus); "
        "under_one_period counts latencies shorter than one period",
        "stop": {
            "method": "dead-man release (LB up) -> both wheel goal speeds 0 at the servos",
            **stop.summary(period),
        },
        "estop_http": {
            "method": "POST /api/estop {engaged: true} sent -> both wheel goal "
            "speeds 0 at the servos; reply_ms is the HTTP round trip",
            **estop_http.summary(period),
        },
        "estop_ws": {
            "method": "WebSocket {type: estop, engaged: true, id} sent -> both wheel "
            "goal speeds 0 at the servos; reply_ms is the reply's round trip",
            **estop_ws.summary(period),
        },
        "teleop": {
            "method": "stick change with LB held -> the left wheel's new goal speed at the servos",
            **teleop.summary(period),
        },
        "tick_during_run": {
            "method": "ControlLoop.stats over the last 2000 ticks of this "
            "run (in-process, sim in the same loop)",
            **periods,
        },
        "wire": {"method": WIRE_METHOD, "codec": codec, "idle": wire_idle, "driving": wire_drive},
    }


def main(argv: Sequence[str] | None = None) -> int:
    p = output.parser(__doc__, NAME)
    p.add_argument("--releases", type=int, default=200, help="dead-man releases")
    p.add_argument("--estops", type=int, default=100, help="E-stops per channel")
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args(argv)
    releases, estops = (5, 3) if args.smoke else (args.releases, args.estops)
    wire_s = 0.3 if args.smoke else 2.0
    setup_logging("error")  # every E-stop logs a warning: hundreds of lines, none news
    result = asyncio.run(run(releases, estops, wire_s, args.seed))
    output.emit(result, NAME, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
