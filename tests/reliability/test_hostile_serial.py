"""Garbage on the serial line: the tick rides it out, counts it, reads true after, writes nothing.

The simulated bus already injects ``garbage`` (random bytes before a reply, never
0xFF), ``corrupt`` (a wrong checksum) and ``truncate``. :class:`LineNoise` adds what
a noisy line or a confused device does that those cannot: bare ``FF FF`` headers
with nothing after, a well-formed reply from an id nobody asked, a reply of the
wrong length, random bytes *with* 0xFF (fake headers) between replies, and bytes
after the last reply of an exchange. A second test writes bursts of noise straight
into the pty between exchanges. It wraps ``SimulatedBus.respond``,
so every mangled byte goes through the real pty and the daemon's real parser.

For each phase (arm limp, then arm holding with torque on) the test proves:

* the tick keeps its rate and no task restarts;
* the failures are counted in /metrics by kind (garbled, timeout, unexpected_id, ...);
* no write reaches any servo while limp, and while holding no goal changes: a
  garbled reading must never be adopted as a measurement and re-sent as a goal,
  not even one whose garbage passes the one-byte checksum (as 1 in 256 cut replies
  completed by the next servo's bytes do): an arm reading that jumps further than
  the joint can move is held until a second reading confirms it;
* once the line is clean, every reading matches the servo's real registers again.

Every random choice comes from one seeded generator (``$LUPIN_FUZZ_SEED``, printed).
"""

from __future__ import annotations

import asyncio
import contextlib
import random
import time
from collections import Counter
from collections.abc import Iterator

import aiohttp
import pytest

from lupin.daemon import Daemon
from lupin.protocol import Instruction, Packet, status
from lupin_adapters.sim.faults import Reply
from lupintest.harness import Sim

from .helpers import (
    ALL,
    ARM,
    GOAL_POS,
    TORQUE,
    TickLog,
    failures,
    post,
    running_api,
    running_daemon,
    scrape,
)
from .hostile_helpers import assert_nothing_written, fuzz_seed, rng_for

RATE = 0.15  # of replies mangled by LineNoise
FORGE_RATE = 0.03  # of arm readings replaced by a checksum collision (see LineNoise._forge)
T_NOISE = 1.2  # s under noise per phase
MANGLES = (
    "bare header",
    "header after",
    "stranger id",
    "bad checksum",
    "short reply",
    "long reply",
    "noise with FF",
)


class LineNoise:
    """Mangles the simulated servos' replies the way a noisy line would (see module doc)."""

    def __init__(self, sim: Sim, rng: random.Random, rate: float) -> None:
        self.sim, self.rng, self.rate = sim, rng, rate
        self.done: Counter[str] = Counter()
        self._respond = sim.bus.respond
        self._forged_last: dict[int, bool] = {}

    @contextlib.contextmanager
    def on(self) -> Iterator[LineNoise]:
        self.sim.bus.respond = self._noisy  # type: ignore[method-assign]
        try:
            yield self
        finally:
            del self.sim.bus.respond  # back to the class's method

    def _noisy(self, packet: Packet, now: float) -> list[Reply]:
        replies = self._respond(packet, now)
        out = []
        for r in replies:
            forged = (
                packet.code == Instruction.SYNC_READ
                and r.id in ARM
                and len(r.data) == 6 + 6  # intact: header, id, len, error, 6 params, checksum
                and not self._forged_last.get(r.id)
                and self.rng.random() < FORGE_RATE
            )
            self._forged_last[r.id] = forged
            if forged:
                out.append(self._forge(r))
            elif len(r.data) >= 6 and self.rng.random() < self.rate:
                out.append(self._mangle(r))
            else:
                out.append(r)  # (a reply the sim's own faults cut short is left as it is)
        if self.rng.random() < self.rate:
            # Bytes after the last reply: they land after the exchange is over.
            self.done["trailing"] += 1
            out.append(Reply(0, self.rng.randbytes(self.rng.randint(1, 24))))
        return out

    def _forge(self, reply: Reply) -> Reply:
        """What 1 in 256 cut replies become: well formed, checksum right, garbage inside.

        Never two in a row for one servo (such collisions are rare and independent),
        and far from the truth (a near one is indistinguishable from a reading).
        """
        self.done["checksum collision"] += 1
        params = reply.data[5:-1]
        real = int.from_bytes(params[:2], "little")
        fake = real
        while abs(fake - real) < 300:
            fake = self.rng.randrange(4096)
        return Reply(reply.id, status(reply.id, 0, fake.to_bytes(2, "little") + params[2:]))

    def _mangle(self, reply: Reply) -> Reply:
        rng, data = self.rng, reply.data
        kind = rng.choice(MANGLES)
        self.done[kind] += 1
        error, params = data[4], data[5:-1]
        if kind == "bare header":
            data = b"\xff\xff"
        elif kind == "header after":
            data = data + b"\xff\xff"
        elif kind == "stranger id":  # well formed, checksum right, from an id on no profile
            data = status(rng.randint(0x30, 0xFD), error, params)
        elif kind in ("bad checksum", "short reply"):
            data = data[:-1] + bytes([data[-1] ^ rng.randint(1, 255)])
        elif kind == "short reply" and params:  # right id, right checksum, too few bytes
            data = status(reply.id, error, params[: rng.randrange(len(params))])
        elif kind == "long reply":
            data = status(reply.id, error, params + rng.randbytes(rng.randint(1, 6)))
        else:  # random bytes that may fake a header, before and after the reply
            junk = bytes(rng.choice([0xFF, rng.randrange(256)]) for _ in range(rng.randint(1, 12)))
            data = junk + data + junk[::-1]
        return Reply(reply.id, data, reply.delay)


def readings_match(sim: Sim, daemon: Daemon) -> list[str]:
    """Servos whose last reading differs from their registers (position, by > 2 counts)."""
    assert daemon.loop is not None
    wrong = []
    for sid in ALL:
        real = sim.bus.servo(sid).get("present_position")
        read = daemon.loop.readings[sid].position
        if abs(real - read) > 2 or daemon.loop.readings[sid].misses:
            wrong.append(f"id {sid}: read {read}, real {real}")
    return wrong


async def noisy_phase(
    sim: Sim, daemon: Daemon, noise: LineNoise, http: aiohttp.ClientSession, url: str
) -> tuple[dict[str, float], float]:
    """T_NOISE s of LineNoise plus the sim's own garbage/corrupt/truncate faults.

    Returns (failure counters grown, ticks per second under noise).
    """
    ticks = TickLog(daemon)
    before = failures(await scrape(http, url))
    for kind in ("garbage", "corrupt", "truncate"):
        sim.bus.inject(kind, rate=RATE / 3)
    t0 = time.monotonic()
    with noise.on():
        await asyncio.sleep(T_NOISE)
    t1 = time.monotonic()
    sim.bus.clear_faults()
    after = failures(await scrape(http, url))
    grown = {k: after[k] - before.get(k, 0) for k in after if after[k] > before.get(k, 0)}
    assert daemon.loop is not None
    daemon.loop.on_state.remove(ticks._on_state)
    return grown, ticks.tick_hz(t0, t1)


async def recovered(sim: Sim, daemon: Daemon) -> None:
    """After the noise: within a few ticks, every reading is true again."""
    deadline = time.monotonic() + 1.0
    while wrong := readings_match(sim, daemon):
        assert time.monotonic() < deadline, f"readings still wrong after the noise: {wrong}"
        await asyncio.sleep(0.02)


async def test_garbage_on_the_line_is_counted_read_through_and_moves_nothing(
    sim: Sim, http: aiohttp.ClientSession, caplog: pytest.LogCaptureFixture
) -> None:
    rng = rng_for(fuzz_seed("serial garbage"), "line")
    sim.bus.rng.seed(rng.randrange(2**32))  # the sim's own faults replay too
    noise = LineNoise(sim, rng, RATE)
    async with running_daemon(sim) as daemon, running_api(daemon) as api:
        hz = daemon.profile.control.tick_hz

        # Phase 1: the arm limp. Not one write may reach any servo.
        t0 = time.monotonic()
        grown, tick_hz = await noisy_phase(sim, daemon, noise, http, api.url)
        assert_nothing_written(sim, t0, "garbage on the line (arm limp)")
        assert tick_hz > 0.8 * hz, f"the tick slowed to {tick_hz:.0f} Hz under garbage"
        expected = {"garbled", "timeout", "unexpected_id", "wrong_length", "implausible"}
        assert expected <= set(grown), grown
        await recovered(sim, daemon)

        # Phase 2: the arm energised and holding. Its goals must not change.
        status_code, body = await post(http, api.url + "/api/arm/torque", {"enabled": True})
        assert (status_code, body) == (200, {"torque": "on"})
        await asyncio.sleep(0.3)  # the seeded hold goals have gone out
        held = {sid: sim.bus.servo(sid).get("goal_position") for sid in range(1, 7)}
        t1 = time.monotonic()
        grown2, tick_hz = await noisy_phase(sim, daemon, noise, http, api.url)
        assert tick_hz > 0.8 * hz, f"the tick slowed to {tick_hz:.0f} Hz under garbage"
        assert {"garbled", "timeout", "implausible"} <= set(grown2), grown2
        moved = [
            (w.id, w.value("goal_position"))
            for w in sim.bus.writes_to(GOAL_POS, since=t1)
            if w.value("goal_position") != held.get(w.id)
        ]
        assert not moved, f"garbage on the line changed arm goals: {moved}"
        assert not sim.bus.writes_to(TORQUE, since=t1), "garbage changed the torque"
        assert {sid: sim.bus.servo(sid).get("goal_position") for sid in range(1, 7)} == held
        await recovered(sim, daemon)
        assert daemon.restarts == []
    print(sorted(noise.done.items()), grown, grown2)
    assert set(noise.done) >= {*MANGLES, "trailing", "checksum collision"}, (
        noise.done
    )  # every mangle happened
    errors = [r.getMessage() for r in caplog.records if r.levelno >= 40]
    assert not errors, f"garbage on the line was logged as an error: {errors}"


async def test_a_burst_of_pure_noise_between_ticks_is_dropped_not_parsed(
    sim: Sim, http: aiohttp.ClientSession
) -> None:
    """Bytes nobody asked for, straight into the pty between exchanges, headers included."""
    rng = rng_for(fuzz_seed("serial noise"), "burst")
    async with running_daemon(sim) as daemon, running_api(daemon) as api:
        before = failures(await scrape(http, api.url))
        t0 = time.monotonic()
        for _ in range(40):
            burst = bytes(rng.choice([0xFF, rng.randrange(256)]) for _ in range(rng.randint(1, 64)))
            sim.server._send(burst)  # the master end of the pty: as if the line produced it
            await asyncio.sleep(rng.uniform(0.0, 0.02))
        await asyncio.sleep(0.1)
        after = failures(await scrape(http, api.url))
        assert after.get("stray_bytes", 0) + after.get("garbled", 0) > before.get(
            "stray_bytes", 0
        ) + before.get("garbled", 0), (before, after)
        assert_nothing_written(sim, t0, "noise between exchanges")
        await recovered(sim, daemon)
        assert daemon.restarts == []
