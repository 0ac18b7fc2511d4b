"""``lupin bt-fix`` on a temporary main.conf: pin, backup, idempotence, dry run."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pytest

from lupin.cli import main
from lupin.cli.bt_fix import fix, pin_le_intervals

# The shape of BlueZ 5.64's stock /etc/bluetooth/main.conf (abridged).
STOCK = """\
[General]

# Default adapter name
# Defaults to 'BlueZ X.YZ'
#Name = BlueZ

# Restricts all controllers to the specified transport. Default value
# is "dual", i.e. both BR/EDR and LE enabled (when supported by the HW).
#ControllerMode = dual

[BR]
#PageScanType=

[LE]
# The following values are used to load default adapter parameters for LE.
# These are applied only when the controller supports LE.
#MinAdvertisementInterval=
#MaxAdvertisementInterval=
#MultiAdvertisementRotationInterval=
#ScanIntervalAutoConnect=
#MinConnectionInterval=
#MaxConnectionInterval=
#ConnectionLatency=
#ConnectionSupervisionTimeout=
#Autoconnecttimeout=

[GATT]
# GATT attribute cache.
#Cache = always

[Policy]
#AutoEnable=true
"""


class Commands:
    def __init__(self, code: int = 0) -> None:
        self.code = code
        self.ran: list[list[str]] = []

    def __call__(self, cmd: Sequence[str]) -> int:
        self.ran.append(list(cmd))
        return self.code


def run(conf: Path, **kwargs: object) -> tuple[int, str, Commands]:
    lines: list[str] = []
    commands = kwargs.pop("runner", Commands())
    assert isinstance(commands, Commands)
    code = fix(
        conf,
        runner=commands,
        which=kwargs.pop("which", lambda name: f"/usr/bin/{name}"),  # type: ignore[arg-type]
        out=lines.append,
        **kwargs,  # type: ignore[arg-type]
    )
    return code, "\n".join(lines), commands


def test_commented_defaults_become_set_and_everything_else_is_kept() -> None:
    new = pin_le_intervals(STOCK)
    le = new.split("[LE]")[1].split("[GATT]")[0]
    assert "\nMinConnectionInterval=7\n" in le
    assert "\nMaxConnectionInterval=9\n" in le
    assert "\nConnectionLatency=0\n" in le
    assert "#MinConnectionInterval=" not in new
    removed = set(STOCK.splitlines()) - set(new.splitlines())
    assert removed == {"#MinConnectionInterval=", "#MaxConnectionInterval=", "#ConnectionLatency="}
    assert new.count("\n") == STOCK.count("\n")  # replaced in place, nothing moved
    assert pin_le_intervals(new) == new


def test_missing_section_is_added_and_wrong_values_are_replaced() -> None:
    text = "[General]\nName = robot\n"
    new = pin_le_intervals(text)
    assert new == (
        "[General]\nName = robot\n\n[LE]\n"
        "MinConnectionInterval=7\nMaxConnectionInterval=9\nConnectionLatency=0\n"
    )
    text = "[LE]\nMinConnectionInterval = 6\nScanWindowSuspend=10\n\n[GATT]\nCache=always"
    new = pin_le_intervals(text)
    assert new == (
        "[LE]\nMinConnectionInterval=7\nScanWindowSuspend=10\nMaxConnectionInterval=9\n"
        "ConnectionLatency=0\n\n[GATT]\nCache=always\n"
    )
    assert pin_le_intervals("") == (
        "[LE]\nMinConnectionInterval=7\nMaxConnectionInterval=9\nConnectionLatency=0\n"
    )


def test_a_key_in_another_section_is_not_touched() -> None:
    text = "[BR]\nMinConnectionInterval=3\n[LE]\n"
    new = pin_le_intervals(text)
    assert new.startswith("[BR]\nMinConnectionInterval=3\n[LE]\nMinConnectionInterval=7\n")


def test_fix_backs_up_first_restarts_and_removes_the_bond(tmp_path: Path) -> None:
    conf = tmp_path / "main.conf"
    conf.write_text(STOCK)
    code, out, commands = run(conf, device="44:16:22:AA:BB:CC")
    assert code == 0
    assert (tmp_path / "main.conf.bak").read_text() == STOCK
    assert "MinConnectionInterval=7" in conf.read_text()
    assert commands.ran == [
        ["systemctl", "restart", "bluetooth"],
        ["bluetoothctl", "remove", "44:16:22:AA:BB:CC"],
    ]
    assert "re-pair" in out


def test_second_run_changes_nothing_and_says_so(tmp_path: Path) -> None:
    conf = tmp_path / "main.conf"
    conf.write_text(STOCK)
    run(conf)
    pinned = conf.read_text()
    backup = tmp_path / "main.conf.bak"
    backup.write_text("sentinel")  # a second run must not overwrite the backup
    code, out, commands = run(conf)
    assert code == 0
    assert conf.read_text() == pinned and backup.read_text() == "sentinel"
    assert "already pinned; nothing to change" in out
    assert commands.ran == []  # no restart either


def test_dry_run_prints_the_diff_and_writes_nothing(tmp_path: Path) -> None:
    conf = tmp_path / "main.conf"
    conf.write_text(STOCK)
    code, out, commands = run(conf, dry_run=True, device="44:16:22:AA:BB:CC")
    assert code == 0
    assert conf.read_text() == STOCK and not (tmp_path / "main.conf.bak").exists()
    assert f"--- {conf}" in out and "-#MinConnectionInterval=" in out
    assert "+MinConnectionInterval=7" in out and "+ConnectionLatency=0" in out
    assert "dry run: would restart bluetooth" in out
    assert commands.ran == []


def test_missing_binaries_are_skipped_with_a_message(tmp_path: Path) -> None:
    conf = tmp_path / "main.conf"
    conf.write_text(STOCK)
    code, out, commands = run(conf, device="44:16:22:AA:BB:CC", which=lambda name: None)
    assert code == 0 and commands.ran == []
    assert "skipped: cannot restart bluetooth: systemctl not found" in out
    assert "bluetoothctl remove 44:16:22:AA:BB:CC" in out


def test_failed_command_and_bad_mac(tmp_path: Path) -> None:
    conf = tmp_path / "main.conf"
    conf.write_text(STOCK)
    code, out, _ = run(conf, runner=Commands(code=1))
    assert code == 1 and "failed (exit 1)" in out
    code, out, _ = run(conf, device="not-a-mac")
    assert code == 2 and "is not a MAC address" in out


def test_cli_dry_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    conf = tmp_path / "main.conf"
    conf.write_text("[General]\n")
    assert main(["bt-fix", "--main-conf", str(conf), "--dry-run"]) == 0
    assert "+[LE]" in capsys.readouterr().out
    assert conf.read_text() == "[General]\n"
