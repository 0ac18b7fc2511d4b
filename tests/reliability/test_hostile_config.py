"""Malformed configs and overlays: ``lupin run`` refuses each at once, by file and field, and
never talks to the bus.

Each fixed case runs the real command (``python -m lupin run``) as a child process
against an in-test simulated bus (``--bus-port``), so "never opened the bus, never
moved" is judged where it matters: not one packet reached a servo. Each must exit 2
within seconds, with a message on stderr naming the file and the field (or the
line) and no traceback. A few run with ``--sim`` too, the daemon's own simulator.

Then a seeded set of random mutations of the real so101 profile, and of an
``arm.yaml`` overlay, goes through the loader ``lupin run`` uses: each must either
load or raise ConfigError naming the file; anything else is a traceback. A sample of
the refused ones also goes through the real command.
"""

from __future__ import annotations

import asyncio
import copy
import math
import os
import random
import string
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml

from lupin.config import ConfigError, load_profile, read_yaml
from lupin.daemon import Daemon, DaemonOptions
from lupintest.harness import Sim, child_env, lupin_cmd

from .helpers import free_port
from .hostile_helpers import fuzz_seed, rng_for

PROFILE = Path(__file__).parents[2] / "config/robots/so101.yaml"
EXIT_CONFIG = 2
PROMPT_S = 5.0  # "promptly": a refusal is a parse, not a wait
STILL_RUNNING = -999
MUTATIONS = 300  # random profile mutations through the loader (in process)
OVERLAY_MUTATIONS = 150
SAMPLE_CLI = 4  # of the refused random mutations, also run through `lupin run`
PARALLEL = 2  # children at once (2 cores)

OVERLAY_OK = (
    "joints:\n"
    "  elbow_flex: {zero: 2100, min: 1100, max: 3000}\n"
    "  wrist_flex: {zero: 2000, min: 1000, max: 3000}\n"
)


@dataclass(frozen=True)
class Case:
    name: str
    config: str | bytes | None = None  # the --config file; None: no --config
    overlay: str | bytes | None = None  # $LUPIN_HOME/arm.yaml
    needles: tuple[str, ...] = ()  # each must appear on stderr
    profile: str | None = None  # --profile: "DIR" for a directory, "EMPTY" for an empty file
    config_path: str | None = None  # --config naming a special path ("DIR", "MISSING", ...)
    sim: bool = False  # --sim instead of the test's bus


CASES: list[Case] = [
    Case(
        "truncated YAML",
        "arm:\n  envelope_deg: 90\n  joints:\n    - {name: shoulder_pan, id: ",
        needles=("not valid YAML", "line 4"),
    ),
    Case(
        "tabs", "control:\n\ttick_hz: 100\n", needles=("not valid YAML", "cannot start any token")
    ),
    Case("wrong type", "control: {tick_hz: fast}\n", needles=("control.tick_hz", "valid number")),
    Case("NaN", "arm: {envelope_deg: .nan}\n", needles=("arm.envelope_deg", "finite")),
    Case("infinity", "base: {max_wheel_speed_rad_s: .inf}\n", needles=("base", "finite")),
    Case("unknown key", "arm: {envelop_deg: 80}\n", needles=("arm.envelop_deg", "Extra inputs")),
    Case(
        "arm id equal to a wheel id",
        "base:\n  wheels:\n    - {name: left, id: 3}\n    - {name: right, id: 9}\n",
        needles=("base.wheels[0] (left).id", "already used by arm.joints[2] (elbow_flex)"),
    ),
    Case(
        "duplicate names",
        "arm:\n  joints:\n    - {name: a, id: 1}\n    - {name: a, id: 2}\n",
        needles=("arm.joints[1] (a).name", "duplicate name"),
    ),
    Case(
        "out-of-range limit",
        "arm:\n  joints:\n    - {name: a, id: 1, zero: 2048, min: 1000, max: 5000}\n",
        needles=("arm.joints[0] (a).max", "4095"),
    ),
    Case(
        "min above max",
        "arm:\n  joints:\n    - {name: a, id: 1, zero: 2048, min: 3000, max: 2000}\n",
        needles=("arm.joints[0] (a).min", "below max"),
    ),
    Case(
        "body limit below its floor",
        "api: {max_body_bytes: 100}\n",
        needles=("api.max_body_bytes", "256"),
    ),
    Case("binary garbage", bytes(range(256)) * 4, needles=("cannot read", "utf-8")),
    Case("a list at the top", "- 1\n- 2\n", needles=("expected a mapping",)),
    Case(
        "a key given twice",
        "control: {tick_hz: 50}\ncontrol: {tick_hz: 100}\n",
        needles=("duplicate key 'control'", "line 2"),
    ),
    Case("deep nesting", "a: " + "[" * 5000 + "]" * 5000 + "\n", needles=("nested too deeply",)),
    Case(
        "a 5000-digit number",
        "control: {tick_hz: 1" + "0" * 5000 + "}\n",
        needles=("not valid YAML", "digits"),
    ),
    Case(
        "a python tag",
        "control: !!python/object/apply:os.system ['touch PWNED']\n",
        needles=("not valid YAML", "python/object/apply"),
    ),
    Case("a directory", config_path="DIR", needles=("cannot read", "Is a directory")),
    Case("missing", config_path="MISSING", needles=("no such file",)),
    Case("unreadable", config_path="UNREADABLE", needles=("cannot read",)),
    Case(
        "arm not a mapping, with an overlay",
        "arm: 5\n",
        OVERLAY_OK,
        needles=("arm:", "valid dictionary"),
    ),
    # $LUPIN_HOME/arm.yaml, this arm's calibration.
    Case(
        "overlay truncated",
        overlay="joints: {elbow_flex: {zero: ",
        needles=("arm.yaml", "not valid YAML"),
    ),
    Case(
        "overlay unknown joint",
        overlay="joints: {knee: {zero: 1, min: 0, max: 2}}\n",
        needles=("arm.yaml", "joints.knee", "not a joint of this profile"),
    ),
    Case(
        "overlay zero outside",
        overlay="joints: {elbow_flex: {zero: 10, min: 100, max: 200}}\n",
        needles=("arm.yaml", "(elbow_flex).zero", "outside its limits"),
    ),
    Case(
        "overlay wrong type",
        overlay="joints: {elbow_flex: {zero: x, min: 1, max: 2}}\n",
        needles=("arm.yaml", "joints.elbow_flex.zero"),
    ),
    Case(
        "overlay unknown key",
        overlay="joints: {elbow_flex: {zero: 5, min: 1, max: 9, z: 1}}\n",
        needles=("arm.yaml", "joints.elbow_flex.z", "Extra inputs"),
    ),
    Case(
        "overlay binary", overlay=b"\x89PNG\r\n\x1a\n\x00\xff", needles=("arm.yaml", "cannot read")
    ),
    Case(
        "overlay twice",
        overlay=OVERLAY_OK + "joints: {}\n",
        needles=("arm.yaml", "duplicate key 'joints'"),
    ),
    Case("overlay a directory", overlay="DIR", needles=("arm.yaml", "Is a directory")),
    # --profile PATH
    Case("profile a directory", profile="DIR", needles=("cannot read", "Is a directory")),
    Case("profile empty", profile="EMPTY", needles=("empty.yaml", "name", "Field required")),
    # The daemon's own simulator: still refused before it is built.
    Case("NaN with --sim", "arm: {envelope_deg: .nan}\n", needles=("arm.envelope_deg",), sim=True),
    Case(
        "overlay with --sim",
        overlay="joints: {knee: {zero: 1, min: 0, max: 2}}\n",
        needles=("joints.knee",),
        sim=True,
    ),
]


def _write(path: Path, content: str | bytes) -> None:
    if content == "DIR":
        path.mkdir()
    elif isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)


def arguments(case: Case, work: Path, home: Path) -> list[str]:
    """The command line for ``case``; writes its files under ``work`` and ``home``."""
    args: list[str] = []
    if case.config is not None:
        _write(work / "site.yaml", case.config)
        args += ["--config", str(work / "site.yaml")]
    special = {
        "DIR": str(work),
        "MISSING": str(work / "missing.yaml"),
        # Root reads a 000 file anyway; /proc/self/mem is unreadable (EIO) to anyone.
        "UNREADABLE": "/proc/self/mem" if os.geteuid() == 0 else str(work / "locked.yaml"),
    }
    if case.config_path is not None:
        if case.config_path == "UNREADABLE" and os.geteuid() != 0:
            (work / "locked.yaml").write_text("control: {tick_hz: 100}\n")
            (work / "locked.yaml").chmod(0)
        args += ["--config", special[case.config_path]]
    if case.overlay is not None:
        _write(home / "arm.yaml", case.overlay)
    if case.profile == "DIR":
        (work / "robot.yaml").mkdir()
        args += ["--profile", str(work / "robot.yaml")]
    elif case.profile == "EMPTY":
        (work / "empty.yaml").write_text("")
        args += ["--profile", str(work / "empty.yaml")]
    return args


async def run_refused(
    sim: Sim, args: list[str], home: Path, cwd: Path | None = None
) -> tuple[int, str, float]:
    """``lupin run ARGS`` on the test's bus: (exit status, stderr, seconds it took).

    A child still running after PROMPT_S started serving: it is stopped, and its
    status is reported as STILL_RUNNING with what it printed.
    """
    bus = [] if "--sim" in args else ["--bus-port", sim.path]
    start = time.monotonic()
    proc = await asyncio.create_subprocess_exec(
        *lupin_cmd("run", "--port", str(free_port()), "--pad", "none", *bus, *args),
        stdout=asyncio.subprocess.DEVNULL,
        stderr=asyncio.subprocess.PIPE,
        env=child_env(home),
        cwd=cwd,
    )
    assert proc.stderr is not None
    try:
        async with asyncio.timeout(PROMPT_S):
            await proc.wait()
    except TimeoutError:
        proc.kill()
        await proc.wait()
        return STILL_RUNNING, (await proc.stderr.read()).decode(errors="replace"), PROMPT_S
    err = (await proc.stderr.read()).decode(errors="replace")
    assert proc.returncode is not None
    return proc.returncode, err, time.monotonic() - start


def assert_clear_refusal(code: int, err: str, took: float, needles: tuple[str, ...]) -> None:
    assert code == EXIT_CONFIG, f"exit {code}, wanted {EXIT_CONFIG}:\n{err}"
    assert "Traceback" not in err, err
    assert "configuration error" in err, err
    assert "ready:" not in err and "API listening" not in err, err
    for needle in needles:
        assert needle in err, f"{needle!r} not in:\n{err}"
    assert took < PROMPT_S, f"took {took:.1f} s to refuse"


async def test_each_malformed_config_is_refused_by_name_before_the_bus(
    sim: Sim, tmp_path: Path
) -> None:
    gate = asyncio.Semaphore(PARALLEL)
    t0 = time.monotonic()

    async def one(i: int, case: Case) -> str | None:
        work = tmp_path / f"case{i}"
        home = tmp_path / f"home{i}"
        work.mkdir()
        home.mkdir()
        args = arguments(case, work, home) + (["--sim"] if case.sim else [])
        async with gate:
            code, err, took = await run_refused(sim, args, home, cwd=work)
        try:
            named = [str(work / "site.yaml")] if case.config is not None else []
            named += [str(home / "arm.yaml")] if case.overlay is not None else []
            assert_clear_refusal(code, err, took, (*case.needles, *named))
        except AssertionError as exc:
            return f"{case.name}: {exc}"
        return None

    failures = await asyncio.gather(*(one(i, c) for i, c in enumerate(CASES)))
    assert not [f for f in failures if f], "\n\n".join(f for f in failures if f)
    # Never opened the bus, never moved: not one packet reached a servo.
    assert not sim.bus.instructions(0x02, since=t0) and not list(sim.bus.received), [
        p for _, p in list(sim.bus.received)[:5]
    ]
    assert not files_named(tmp_path, "PWNED"), "a YAML tag ran a command"


def files_named(root: Path, name: str) -> list[Path]:
    return list(root.rglob(name))


# -- random mutations of the real profile ------------------------------------------------------


def _random_scalar(rng: random.Random) -> Any:
    return rng.choice(
        [
            None,
            True,
            0,
            -1,
            4096,
            10**20,
            1e308,
            math.nan,
            math.inf,
            -math.inf,
            0.5,
            "",
            "x",
            "\u2603",
            [],
            {},
            [1, "a"],
            {"zz_unknown": 1},
        ]
    )


def _paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [prefix]
    if isinstance(node, dict):
        for key, value in node.items():
            out += _paths(value, (*prefix, key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            out += _paths(value, (*prefix, i))
    return out


def _mutate_tree(rng: random.Random, data: dict[str, Any]) -> dict[str, Any]:
    data = copy.deepcopy(data)
    for _ in range(rng.randint(1, 3)):
        paths = _paths(data)[1:]
        if not paths:
            break  # everything was deleted already
        path = rng.choice(paths)
        parent: Any = data
        for part in path[:-1]:
            parent = parent[part]
        last = path[-1]
        action = rng.random()
        if action < 0.6:
            parent[last] = _random_scalar(rng)
        elif action < 0.8:
            del parent[last]
        elif isinstance(parent, dict):
            parent["zz_" + "".join(rng.choices(string.ascii_lowercase, k=5))] = 1
        else:
            parent.append(copy.deepcopy(parent[last]))  # a duplicate entry (ids, names)
    return data


def _mutate_text(rng: random.Random, text: str) -> str | bytes:
    kind = rng.randrange(6)
    at = rng.randrange(len(text))
    if kind == 0:
        return text[:at]  # truncated
    if kind == 1:
        return text[:at] + text[at + rng.randint(1, 40) :]  # a span deleted
    if kind == 2:
        junk = "".join(rng.choices("\t :{}[],-#&*!|>'\"%@`\\\n\u00e9", k=rng.randint(1, 8)))
        return text[:at] + junk + text[at:]
    if kind == 3:
        lines = text.splitlines(keepends=True)
        i = rng.randrange(len(lines))
        return "".join([*lines[: i + 1], lines[i], *lines[i + 1 :]])  # a line twice
    if kind == 4:
        raw = bytearray(text.encode())
        for _ in range(rng.randint(1, 4)):
            raw[rng.randrange(len(raw))] = rng.randrange(256)
        return bytes(raw)  # bit rot
    return text.replace(
        rng.choice(["2048", "0.05", "100", "true", "1000000"]),
        rng.choice([".nan", ".inf", "-1", "1e999", "'x'", "[]", "{}", "~", "0x1F", "2_048"]),
        1,
    )


Check = Callable[[Path, Path], Any]


def _loads_or_refuses(path: Path, load: Check, home: Path) -> str:
    """'loaded' or 'refused'; anything but ConfigError escapes (a traceback in `lupin run`)."""
    try:
        profile = load(path, home)
    except ConfigError as exc:
        assert str(path) in str(exc), f"the refusal does not name {path}: {exc}"
        return "refused"
    # What loads must also build a daemon (geometry, mux, base) without a crash.
    Daemon(profile, DaemonOptions(sim=True, auto_home=False))
    return "loaded"


def test_random_profile_mutations_load_or_are_refused_never_a_traceback(
    tmp_path: Path,
) -> None:
    rng = rng_for(fuzz_seed("config mutations"), "profile")
    text = PROFILE.read_text()
    tree = read_yaml(PROFILE)
    home = tmp_path / "home"
    home.mkdir()
    outcomes: dict[str, int] = {"loaded": 0, "refused": 0}
    for i in range(MUTATIONS):
        path = tmp_path / f"m{i}.yaml"
        if rng.random() < 0.5:
            content: str | bytes = _mutate_text(rng, text)
        else:
            content = yaml.safe_dump(_mutate_tree(rng, tree), allow_unicode=True)
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content)
        as_profile = rng.random() < 0.5

        def load(p: Path, h: Path, as_profile: bool = as_profile) -> Any:
            return (
                load_profile(str(p), home=h) if as_profile else load_profile(config_file=p, home=h)
            )

        try:
            outcomes[_loads_or_refuses(path, load, home)] += 1
        except Exception as exc:
            raise AssertionError(f"mutation {i} ({path.read_bytes()[:300]!r}): {exc!r}") from exc
    print(outcomes)
    assert outcomes["refused"] > MUTATIONS / 4  # the mutations really were hostile


def test_random_overlay_mutations_load_or_are_refused_never_a_traceback(tmp_path: Path) -> None:
    rng = rng_for(fuzz_seed("config mutations"), "overlay")
    tree = read_yaml_text(OVERLAY_OK)
    outcomes: dict[str, int] = {"loaded": 0, "refused": 0}
    for i in range(OVERLAY_MUTATIONS):
        home = tmp_path / f"h{i}"
        home.mkdir()
        overlay = home / "arm.yaml"
        if rng.random() < 0.5:
            content: str | bytes = _mutate_text(rng, OVERLAY_OK)
        else:
            content = yaml.safe_dump(_mutate_tree(rng, tree), allow_unicode=True)
        if isinstance(content, bytes):
            overlay.write_bytes(content)
        else:
            overlay.write_text(content)
        try:
            outcomes[_loads_or_refuses(overlay, lambda p, h: load_profile(home=h), home)] += 1
        except Exception as exc:
            raise AssertionError(f"overlay {i} ({overlay.read_bytes()[:300]!r}): {exc!r}") from exc
    print(outcomes)
    assert outcomes["refused"] > OVERLAY_MUTATIONS / 4


def read_yaml_text(text: str) -> dict[str, Any]:
    data = yaml.safe_load(text)
    assert isinstance(data, dict)
    return data


async def test_a_sample_of_random_mutations_through_lupin_run(sim: Sim, tmp_path: Path) -> None:
    rng = rng_for(fuzz_seed("config mutations"), "cli")
    text = PROFILE.read_text()
    home = tmp_path / "home"
    home.mkdir()
    t0 = time.monotonic()
    sampled = 0
    for i in range(200):
        if sampled == SAMPLE_CLI:
            break
        path = tmp_path / f"cli{i}.yaml"
        content = _mutate_text(rng, text)
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content)
        try:
            load_profile(str(path), home=home)
            continue  # it loads: not a refusal to check
        except ConfigError:
            pass
        sampled += 1
        code, err, took = await run_refused(sim, ["--profile", str(path)], home)
        assert_clear_refusal(code, err, took, (str(path),))
    assert sampled == SAMPLE_CLI
    assert not list(sim.bus.received) or all(t < t0 for t, _ in sim.bus.received)


@pytest.mark.parametrize("content", ["", "# nothing here\n"])
def test_an_empty_site_config_or_overlay_is_a_valid_no_op(tmp_path: Path, content: str) -> None:
    """Documented choice: an empty --config or arm.yaml changes nothing (all commented out)."""
    home = tmp_path / "home"
    home.mkdir()
    plain = load_profile(home=home)
    site = tmp_path / "site.yaml"
    site.write_text(content)
    (home / "arm.yaml").write_text(content)
    assert load_profile(config_file=site, home=home) == plain
