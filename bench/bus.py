"""Bus benchmark: Lupin's asyncio ServoBus against the vendor SDK on one wire-paced simulated bus.

Prints one JSON document (and writes it to ``bench/results/bus.json``):

* full-state SYNC_READ (present position, speed and load: address 56, 6 bytes,
  every servo of the so101 profile) per second, and CPU seconds per
  transaction, for Lupin's ``ServoBus`` and for ``scservo_sdk`` (``PortHandler``,
  ``PacketHandler(0)``, ``GroupSyncRead``) in a worker thread;
* bytes on the wire per control tick (one SYNC_READ with its replies and one
  2-byte goal SYNC_WRITE to the arm), from the codec and from the link's byte
  counters, and the tick rate 1 Mbaud could carry at most.

The simulator runs in its own process (``python -m lupin sim --wire-pacing``),
so the CPU time of this process is the client's alone, for both clients.

    python bench/bus.py                  # 2000 transactions per client
    python bench/bus.py --smoke          # tiny counts, for the test suite
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import tempfile
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import scservo_sdk as sdk
from benchlib.processes import cpu_seconds, simulator

from lupin import control_table as ct
from lupin import protocol
from lupin.bus import BITS_PER_BYTE, STATUS_OVERHEAD, ServoBus
from lupin.config import load_profile
from lupin_adapters.serial_link import SerialLink
from lupin_adapters.sim.link import sim_specs

STATE = ct.REGISTERS["present_position"]  # 56: position, speed, load
STATE_LEN = 6
GOAL = ct.REGISTERS["goal_position"]
TICK_HZ = 100  # the daemon's default control.tick_hz, for the utilisation figure
RESULTS = Path(__file__).resolve().parent / "results" / "bus.json"


@dataclass
class Setup:
    baud: int
    reply_margin_s: float  # the profile's, as the daemon uses them
    retries: int
    ids: list[int]  # every servo on the bus
    arm_ids: list[int]  # the joints a goal SYNC_WRITE addresses
    goals: dict[int, bytes]  # their present positions as goal bytes

    async def bus(self, path: str) -> ServoBus:
        link = await SerialLink.open(path, self.baud)
        return ServoBus(link, reply_margin_s=self.reply_margin_s, retries=self.retries)


@dataclass
class Run:
    transactions: int = 0
    wall_s: float = 0.0
    cpu_s: float = 0.0  # the client's CPU (see METHOD)
    process_cpu_s: float = 0.0
    sim_cpu_s: float = 0.0
    failures: Counter[str] = field(default_factory=Counter)

    def add(self, other: Run) -> None:
        self.transactions += other.transactions
        self.wall_s += other.wall_s
        self.cpu_s += other.cpu_s
        self.process_cpu_s += other.process_cpu_s
        self.sim_cpu_s += other.sim_cpu_s
        self.failures.update(other.failures)

    def summary(self) -> dict[str, Any]:
        return {
            "transactions": self.transactions,
            "wall_s": round(self.wall_s, 4),
            "per_second": round(self.transactions / self.wall_s, 1),
            "ms_per_transaction": round(1000 * self.wall_s / self.transactions, 4),
            "cpu_s_per_transaction": self.cpu_s / self.transactions,
            "process_cpu_s_per_transaction": self.process_cpu_s / self.transactions,
            "cpu_fraction_of_wall": round(self.cpu_s / self.wall_s, 4),
            "sim_cpu_s_per_transaction": self.sim_cpu_s / self.transactions,
            "failures": dict(self.failures),
        }


METHOD = (
    "The simulated bus (python -m lupin sim --wire-pacing: so101 profile, 1 Mbaud, "
    "replies paced at 10 bits a byte) runs in a separate process, so this process's CPU "
    "is the client's alone. The clients take turns, never at once (one opener per bus): "
    "ROUNDS rounds of Lupin then the SDK, each opening the port, warming up, then doing "
    "N/ROUNDS back-to-back full-state SYNC_READs (address 56, 6 bytes, every servo), so a "
    "change in machine load hits both alike; figures are sums over the rounds. Lupin: "
    "ServoBus over SerialLink (pyserial-asyncio) in this process's event loop, with the "
    "profile's reply margin and retries as the daemon uses them; cpu = "
    "time.process_time() delta (one thread). scservo_sdk: PortHandler + PacketHandler(0) "
    "+ GroupSyncRead.txRxPacket in a worker thread (asyncio.to_thread) while the loop "
    "idles; cpu = time.thread_time() delta inside that thread, process_cpu = "
    "time.process_time() delta of the whole process. sim_cpu = utime+stime of the "
    "simulator process from /proc (10 ms resolution). Tick bytes: computed from the "
    "codec, and measured from ServoBus.stats.bytes_out/bytes_in over back-to-back ticks "
    "of one SYNC_READ plus one 2-byte goal SYNC_WRITE to the arm."
)


async def bench_lupin(path: str, sim_pid: int, setup: Setup, n: int, warmup: int) -> Run:
    bus = await setup.bus(path)
    try:
        for _ in range(warmup):
            await bus.sync_read(setup.ids, STATE.address, STATE_LEN)
        bus.stats.failures.clear()
        sim0, cpu0, wall0 = cpu_seconds(sim_pid), time.process_time(), time.perf_counter()
        for _ in range(n):
            await bus.sync_read(setup.ids, STATE.address, STATE_LEN)
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        sim = cpu_seconds(sim_pid) - sim0
        return Run(n, wall, cpu, cpu, sim, Counter(bus.stats.failures))
    finally:
        await bus.close()


def sdk_session(path: str, setup: Setup, n: int, warmup: int) -> tuple[float, float, int]:
    """Blocking SDK loop for a worker thread: (wall s, thread CPU s, failed transactions)."""
    port = sdk.PortHandler(path)
    if not port.setBaudRate(setup.baud):  # opens the port at that rate
        raise RuntimeError(f"scservo_sdk could not open {path} at {setup.baud} baud")
    try:
        reader = sdk.GroupSyncRead(port, sdk.PacketHandler(0), STATE.address, STATE_LEN)
        for sid in setup.ids:
            reader.addParam(sid)
        for _ in range(warmup):
            reader.txRxPacket()
        failed = 0
        cpu0, wall0 = time.thread_time(), time.perf_counter()
        for _ in range(n):
            if reader.txRxPacket() != sdk.COMM_SUCCESS:
                failed += 1
        return time.perf_counter() - wall0, time.thread_time() - cpu0, failed
    finally:
        port.closePort()


async def bench_sdk(path: str, sim_pid: int, setup: Setup, n: int, warmup: int) -> Run:
    sim0, cpu0 = cpu_seconds(sim_pid), time.process_time()
    wall, thread_cpu, failed = await asyncio.to_thread(sdk_session, path, setup, n, warmup)
    # process_time and the sim's CPU include the warm-up here: scale them to N.
    share = n / (n + warmup)
    cpu = (time.process_time() - cpu0) * share
    sim = (cpu_seconds(sim_pid) - sim0) * share
    return Run(n, wall, thread_cpu, cpu, sim, +Counter({"failed_transactions": failed}))


def tick_bytes(setup: Setup) -> dict[str, int]:
    """Bytes on the wire for one control tick, from the codec."""
    request = len(protocol.sync_read(STATE.address, STATE_LEN, setup.ids))
    replies = len(setup.ids) * (STATUS_OVERHEAD + STATE_LEN)
    goals = len(protocol.sync_write(GOAL.address, GOAL.size, setup.goals))
    return {
        "sync_read_request": request,
        "sync_read_replies": replies,
        "goal_sync_write": goals,
        "total": request + replies + goals,
    }


async def bench_ticks(path: str, setup: Setup, ticks: int) -> dict[str, float]:
    """Back-to-back control ticks through Lupin's bus; bytes from its link counters."""
    bus = await setup.bus(path)
    try:
        await bus.sync_read(setup.ids, STATE.address, STATE_LEN)  # warm up
        out0, in0, wall0 = bus.stats.bytes_out, bus.stats.bytes_in, time.perf_counter()
        for _ in range(ticks):
            await bus.sync_read(setup.ids, STATE.address, STATE_LEN)
            await bus.sync_write(GOAL.address, GOAL.size, setup.goals)
        wall = time.perf_counter() - wall0
        return {
            "bytes_out_per_tick": (bus.stats.bytes_out - out0) / ticks,
            "bytes_in_per_tick": (bus.stats.bytes_in - in0) / ticks,
            "ticks": ticks,
            "tick_hz_back_to_back": round(ticks / wall, 1),
            "failures": sum(bus.stats.failures.values()),
        }
    finally:
        await bus.close()


async def read_goals(path: str, setup: Setup) -> dict[int, bytes]:
    """The arm's present positions, as goal bytes that would not move it."""
    bus = await setup.bus(path)
    try:
        result = await bus.sync_read(setup.arm_ids, STATE.address, GOAL.size, retries=2)
    finally:
        await bus.close()
    if result.missing:
        raise RuntimeError(f"simulated servos {result.missing} did not answer")
    return result.data


async def run(n: int, ticks: int, warmup: int, rounds: int) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="lupin-bench-") as tmp:
        home = Path(tmp)
        profile = load_profile("so101", home=home)
        specs = sim_specs(profile)
        arm_ids = [j.id for j in profile.arm.joints]
        bus = profile.bus
        setup = Setup(bus.baud, bus.reply_margin_s, bus.retries, [s.id for s in specs], arm_ids, {})
        lupin, vendor = Run(), Run()
        async with simulator(home) as sim_process:
            path, sim_pid = sim_process.path, sim_process.pid
            setup.goals = await read_goals(path, setup)
            for r in range(rounds):
                share = n // rounds + (r < n % rounds)
                lupin.add(await bench_lupin(path, sim_pid, setup, share, warmup))
                vendor.add(await bench_sdk(path, sim_pid, setup, share, warmup))
            measured = await bench_ticks(path, setup, ticks)
    computed = tick_bytes(setup)
    wire_s = computed["total"] * BITS_PER_BYTE / setup.baud
    sync_read_wire_s = (
        (computed["sync_read_request"] + computed["sync_read_replies"]) * BITS_PER_BYTE / setup.baud
    )
    return {
        "benchmark": "bus",
        "config": {
            "profile": "so101",
            "baud": setup.baud,
            "servo_ids": setup.ids,
            "arm_ids": setup.arm_ids,
            "wire_pacing": True,
            "simulator": "separate process: python -m lupin sim --wire-pacing",
            "reply_margin_s": setup.reply_margin_s,
            "transactions": n,
            "rounds": rounds,
            "warmup_per_round": warmup,
            "python": platform.python_version(),
            "cpus": os.cpu_count(),
        },
        "method": METHOD,
        "sync_read": {
            "address": STATE.address,
            "length": STATE_LEN,
            "servos": len(setup.ids),
            "wire_time_s": sync_read_wire_s,
            "max_per_second_at_baud": round(1 / sync_read_wire_s, 1),
            "lupin": lupin.summary(),
            "scservo_sdk": vendor.summary(),
            "sdk_cpu_over_lupin_cpu": round(vendor.cpu_s / lupin.cpu_s, 2),
        },
        "tick": {
            "bytes": computed,
            "measured": measured,
            "wire_time_s": wire_s,
            "max_tick_hz_at_baud": round(1 / wire_s, 1),
            # A fraction of the line's time (0.138, not 13.8 %): wire time x ticks per second.
            "bus_utilisation_fraction_at_100_hz_tick": round(wire_s * TICK_HZ, 4),
        },
    }


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--transactions", type=int, default=2000, help="SYNC_READs per client")
    p.add_argument("--smoke", action="store_true", help="tiny counts (for the test suite)")
    p.add_argument(
        "--output",
        type=Path,
        help=f"where to write the JSON as well (default {RESULTS}; none with --smoke)",
    )
    args = p.parse_args(argv)
    if args.transactions < 1:
        p.error("--transactions must be at least 1")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    n = 20 if args.smoke else args.transactions
    ticks = 10 if args.smoke else max(100, n // 4)
    warmup = 5 if args.smoke else 20
    rounds = 1 if args.smoke else min(4, n)
    result = asyncio.run(run(n, ticks, warmup, rounds))
    text = json.dumps(result, indent=2)
    print(text)
    output = args.output or (None if args.smoke else RESULTS)
    if output is not None:
        output.parent.mkdir(parents=True, exist_ok=True)
        output.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
