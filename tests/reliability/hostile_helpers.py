"""What the hostile-input tests share: a reproducible seed, "nothing moved" judged at the servos.

"Nothing moved" is judged by the packets the simulated servos received, never by
what the daemon says about itself: no WRITE, REG_WRITE or SYNC_WRITE at all
reached any servo (an idle daemon writes nothing: the bus budget of SPEC §2).
"Still ticking" is the SYNC_READ rate the servos saw, plus no restarted task.
"""

from __future__ import annotations

import asyncio
import os
import random
import time

from lupin.daemon import Daemon
from lupin_adapters.sim.bus import WriteRecord
from lupintest.harness import Sim

SEED_ENV = "LUPIN_FUZZ_SEED"


def fuzz_seed(salt: str) -> int:
    """``$LUPIN_FUZZ_SEED`` (to replay a failure) or a fresh one; printed so a failure says it.

    ``salt`` keeps two tests that share a seed from drawing the same sequence.
    """
    base = os.environ.get(SEED_ENV)
    seed = int(base) if base else random.SystemRandom().randrange(2**32)
    print(f"{salt}: fuzz seed {seed} (replay with {SEED_ENV}={seed})")
    return seed


def rng_for(seed: int, salt: str) -> random.Random:
    return random.Random(f"{seed}:{salt}")


def describe_writes(writes: list[WriteRecord]) -> str:
    return "; ".join(
        f"t={w.t:.3f} id={w.id} {w.instruction.name} @{w.address} {w.data.hex()}"
        for w in writes[:10]
    )


def assert_nothing_written(sim: Sim, since: float, what: str) -> None:
    """No write of any register reached any servo since ``since``: nothing moved or changed."""
    writes = sim.bus.writes(since=since)
    assert not writes, f"{what} wrote to the servos: {describe_writes(writes)}"


async def assert_still_ticking(sim: Sim, daemon: Daemon, window: float = 0.5) -> None:
    """The control tick still reads every servo at (nearly) its rate; no task was restarted."""
    t0 = time.monotonic()
    await asyncio.sleep(window)
    reads = len(sim.sync_reads(since=t0))
    hz = daemon.profile.control.tick_hz
    assert reads >= 0.6 * hz * window, f"the tick slowed or stopped: {reads} reads in {window} s"
    assert daemon.restarts == [], f"tasks crashed and were restarted: {daemon.restarts}"
