"""The unit files: ``systemd-analyze verify`` clean, and the promises they carry.

verify exits 0 even on an unknown key or a bad value (it only warns), so the
test demands silence, and proves it would notice with a deliberately broken copy.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from lupin.cli.install_service import RULE, TEMPLATE_EXE, render_unit, source_dir
from lupin.cli.parser import parse_args
from lupin.config import load_profile

UNITS = sorted(p for p in source_dir().iterdir() if p.suffix in (".service", ".timer", ".socket"))
ANALYZE = shutil.which("systemd-analyze")
needs_analyze = pytest.mark.skipif(ANALYZE is None, reason="systemd-analyze is not installed")


def fake_exe(tmp_path: Path) -> str:
    """An existing executable for ExecStart: verify refuses a missing one."""
    exe = tmp_path / "bin" / "lupin"
    exe.parent.mkdir(parents=True, exist_ok=True)
    exe.write_text("#!/bin/sh\nexit 0\n")
    exe.chmod(0o755)
    return str(exe)


def verify(unit: Path) -> subprocess.CompletedProcess[str]:
    assert ANALYZE is not None
    return subprocess.run(
        [ANALYZE, "verify", "--man=no", str(unit)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def directives(text: str) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for line in text.splitlines():
        if line and not line.startswith(("#", "[")) and "=" in line:
            key, _, value = line.partition("=")
            out.setdefault(key.strip(), []).append(value.strip())
    return out


def test_there_is_a_unit() -> None:
    assert [u.name for u in UNITS] == ["lupin.service"]


@needs_analyze
@pytest.mark.parametrize("unit", UNITS, ids=lambda p: p.name)
def test_systemd_analyze_verify_is_silent(unit: Path, tmp_path: Path) -> None:
    copy = tmp_path / unit.name
    copy.write_text(render_unit(unit.read_text(), fake_exe(tmp_path), "root"))
    result = verify(copy)
    assert result.returncode == 0, result.stderr
    assert result.stdout + result.stderr == ""


@needs_analyze
def test_verify_would_notice_a_mistake(tmp_path: Path) -> None:
    text = render_unit((source_dir() / "lupin.service").read_text(), fake_exe(tmp_path), "root")
    broken = tmp_path / "lupin.service"
    broken.write_text(
        text.replace("WatchdogSec=", "WatchdogSecs=").replace("Type=notify", "Type=x")
    )
    out = verify(broken)
    assert "WatchdogSecs" in out.stderr and "service type" in out.stderr
    missing = tmp_path / "missing.service"
    missing.write_text(text.replace(fake_exe(tmp_path), TEMPLATE_EXE))
    assert verify(missing).returncode != 0  # an ExecStart that does not exist


@needs_analyze
def test_hardening_scores_ok(tmp_path: Path) -> None:
    copy = tmp_path / "lupin.service"
    copy.write_text(
        render_unit((source_dir() / "lupin.service").read_text(), fake_exe(tmp_path), "root")
    )
    out = subprocess.run(
        [str(ANALYZE), "security", "--offline=true", "--no-pager", str(copy)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    found = re.search(r"Overall exposure level for \S+: ([\d.]+)", out.stdout + out.stderr)
    if found is None:
        pytest.skip(f"systemd-analyze security --offline unsupported: {out.stderr[:200]}")
    assert float(found.group(1)) <= 3.0, out.stdout[-2000:]


def test_the_service_keeps_its_promises() -> None:
    d = directives((source_dir() / "lupin.service").read_text())
    one = {k: v[-1] for k, v in d.items()}
    assert one["Type"] == "notify" and one["NotifyAccess"] == "main"
    assert one["WatchdogSec"] == "2s"
    assert one["Restart"] == "on-failure" and "RestartSec" in one
    assert "StartLimitIntervalSec" in one and "StartLimitBurst" in one
    assert one["KillSignal"] == "SIGTERM" and one["TimeoutStopSec"] == "5s"
    # ExecStart and the stop helper read the same site config: same bus, same servos.
    assert one["ExecStart"] == f"{TEMPLATE_EXE} run --config /etc/lupin/lupin.yaml"
    assert one["ExecStopPost"] == f"-{TEMPLATE_EXE} stop-helper --config /etc/lupin/lupin.yaml"
    # Devices: closed, except the bus and the pads.
    assert one["DevicePolicy"] == "closed"
    allowed = set(d["DeviceAllow"])
    assert {
        "/dev/lupin_servos rw",
        "char-ttyUSB rw",
        "char-ttyACM rw",
        "char-input rw",
        "char-hidraw rw",
    } <= allowed
    assert set(one["SupplementaryGroups"].split()) == {"dialout", "input"}
    assert one["StateDirectory"] == "lupin" and "LUPIN_HOME=%S/lupin" in d["Environment"]
    assert "PYTHONFAULTHANDLER=1" in " ".join(d["Environment"])  # a watchdog kill shows where
    assert one["NoNewPrivileges"] == "yes" and one["ProtectSystem"] == "strict"
    assert one["ProtectHome"] == "read-only"  # the venv may live in /home
    assert one["RestrictAddressFamilies"].split() == ["AF_UNIX", "AF_INET", "AF_INET6"]
    # The single-opener guard scans /proc for other PIDs: never hide them.
    assert "ProtectProc" not in one and "ProcSubset" not in one and "PrivateDevices" not in one


def test_the_stop_helper_fits_inside_the_stop_timeout() -> None:
    from lupin.cli.stop_helper import BACKSTOP_EXTRA_S

    timeout = parse_args(["stop-helper"]).timeout
    assert timeout + BACKSTOP_EXTRA_S <= 5.0  # TimeoutStopSec covers ExecStopPost too


# -- the udev rule ------------------------------------------------------------------------

_KEY = re.compile(
    r'^(?P<key>[A-Z_]+)(\{(?P<attr>[^}]+)\})?(?P<op>==|!=|\+=|-=|:=|=)"(?P<v>[^"]*)"$'
)
_MATCH_KEYS = {"ACTION", "SUBSYSTEM", "ATTRS", "DRIVERS", "KERNEL", "ATTR", "ENV"}
_ASSIGN_KEYS = {"SYMLINK", "GROUP", "MODE", "ENV", "TAG", "ATTR"}


def rules() -> list[list[dict[str, str]]]:
    out = []
    for line in (source_dir() / RULE).read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        parts = []
        for item in line.split(", "):
            m = _KEY.match(item.strip())
            assert m, f"not a udev key: {item!r} in {line!r}"
            key, op = m["key"], m["op"]
            assert key in (_MATCH_KEYS if op in ("==", "!=") else _ASSIGN_KEYS), item
            parts.append(m.groupdict())
        out.append(parts)
    return out


def test_udev_rule_names_the_bus_for_each_adapter() -> None:
    named = set()
    for rule in rules():
        keys = {(p["key"], p["attr"]): p["v"] for p in rule}
        if ("SYMLINK", None) in keys:
            assert keys[("SUBSYSTEM", None)] == "tty"
            assert keys[("SYMLINK", None)] == "lupin_servos"
            assert keys[("ENV", "ID_MM_DEVICE_IGNORE")] == "1"  # no ModemManager probing
            assert keys[("GROUP", None)] == "dialout" and keys[("MODE", None)] == "0660"
            named.add((keys[("ATTRS", "idVendor")], keys[("ATTRS", "idProduct")]))
    # CH343 (cdc_acm), CH340, FTDI FT232R: the adapters the brief names.
    assert {("1a86", "55d3"), ("1a86", "7523"), ("0403", "6001")} <= named
    latency = [r for r in rules() if any(p["attr"] == "latency_timer" for p in r)]
    assert latency and latency[0][-1]["v"] == "1"  # FTDI's 16 ms default outlasts a tick


def test_profiles_expect_the_name_the_rule_gives() -> None:
    for name in ("so101", "mecanum"):
        assert load_profile(name).bus.port == "/dev/lupin_servos"
