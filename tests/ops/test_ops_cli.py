"""The two operations subcommands are registered and parsed strictly."""

from __future__ import annotations

import subprocess
import sys

import pytest

from lupin.cli.parser import parse_args


def test_both_commands_are_listed() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "lupin", "--help"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert out.returncode == 0
    assert "stop-helper" in out.stdout and "install-service" in out.stdout


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["stop-helper", "--bogus"], "unrecognized arguments: --bogus"),
        (["stop-helper", "--timeout", "0"], "must be above 0"),
        (["stop-helper", "--bus"], "unrecognized arguments: --bus"),  # no abbreviations
        (["install-service", "--dry"], "unrecognized arguments: --dry"),
    ],
)
def test_bad_flags_exit_2(argv: list[str], needle: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        parse_args(argv)
    assert info.value.code == 2
    assert needle in capsys.readouterr().err


def test_defaults() -> None:
    stop = parse_args(["stop-helper"])
    assert (stop.profile, stop.config, stop.bus_port, stop.timeout) == (None, None, None, 3.0)
    inst = parse_args(["install-service"])
    assert (inst.dry_run, inst.user, inst.prefix, inst.profile, inst.root) == (
        False,
        None,
        None,
        "so101",
        "/",
    )
