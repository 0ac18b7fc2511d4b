"""Strict command-line parsing, checked through the real console entry point."""

from __future__ import annotations

import subprocess
import sys

import pytest

from lupin.cli.parser import parse_args

SUBCOMMANDS = [
    "run",
    "sim",
    "check",
    "calibrate",
    "offsets",
    "gains",
    "pose",
    "jog",
    "heal",
    "pad-calibrate",
    "pad-record",
    "bt-fix",
    "stop-helper",
    "install-service",
]


def lupin(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "lupin", *args], capture_output=True, text=True, timeout=60
    )


def test_every_subcommand_is_registered() -> None:
    out = lupin("--help")
    assert out.returncode == 0
    for name in SUBCOMMANDS:
        assert name in out.stdout


def test_unknown_flag_exits_2_with_usage() -> None:
    out = lupin("run", "--sim", "--bogus")
    assert out.returncode == 2
    assert "usage: lupin run" in out.stderr
    assert "unrecognized arguments: --bogus" in out.stderr


def test_abbreviated_flag_is_not_guessed() -> None:
    # `--pro` must not silently mean `--profile`.
    out = lupin("run", "--pro", "so101")
    assert out.returncode == 2
    assert "--pro" in out.stderr


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["run", "--port", "70000"], "port out of range"),
        (["run", "--pad", "joystick"], "bad pad 'joystick'"),
        (["run", "--pad", "hid:zz:1"], "bad hid id"),
        (["run", "--pad-layout", "xbox"], "invalid choice: 'xbox'"),
        (["pose", "go", "home", "--max-travel", "nan"], "not a finite number"),
        (["pose", "go", "home", "--speed", "-1"], "must be above 0"),
        (["calibrate", "--margin", "abc"], "not a number"),
        (["offsets", "wipe"], "invalid choice: 'wipe'"),
        (["run", "--log-level", "loud"], "invalid choice: 'loud'"),
        (["teleport"], "invalid choice: 'teleport'"),
    ],
)
def test_bad_values_exit_2(
    argv: list[str], needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as info:
        parse_args(argv)
    assert info.value.code == 2
    assert needle in capsys.readouterr().err


def test_good_flags_parse() -> None:
    args = parse_args(
        [
            "run",
            "--sim",
            "--profile",
            "mecanum",
            "--port",
            "0",
            "--pad",
            "replay:/tmp/x.jsonl",
            "--pad-layout",
            "xbox-bluetooth",
            "--bus-port",
            "/dev/pts/3",
            "--log-level",
            "debug",
        ]
    )
    assert (args.sim, args.profile, args.port, args.pad) == (
        True,
        "mecanum",
        0,
        "replay:/tmp/x.jsonl",
    )
    assert (args.pad_layout, args.bus_port, args.log_level) == (
        "xbox-bluetooth",
        "/dev/pts/3",
        "debug",
    )


def test_every_subcommand_has_a_handler_that_imports() -> None:
    import importlib

    import lupin.cli as cli

    assert set(cli.HANDLERS) == set(SUBCOMMANDS)
    for target in cli.HANDLERS.values():
        module_name, func_name = target.split(":")
        assert callable(getattr(importlib.import_module(module_name), func_name)), target
