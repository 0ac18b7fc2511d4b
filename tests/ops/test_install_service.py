"""``lupin install-service``: --dry-run writes nothing; --root DIR installs for real into DIR."""

from __future__ import annotations

import io
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from lupin.cli import main
from lupin.cli.install_service import (
    RULE,
    SITE_CONFIG,
    Command,
    execute,
    source_dir,
)
from lupin.config import load_profile

ANALYZE = shutil.which("systemd-analyze")
EXPECTED = [
    "/etc/systemd/system/lupin.service",
    "/etc/udev/rules.d/99-lupin-servos.rules",
    "/etc/lupin/lupin.yaml",
    "/etc/profile.d/lupin.sh",
]


def install(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "lupin", "install-service", *args],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def prefix_with_lupin(tmp_path: Path) -> Path:
    prefix = tmp_path / "venv"
    (prefix / "bin").mkdir(parents=True)
    exe = prefix / "bin" / "lupin"
    exe.write_text("#!/bin/sh\nexit 0\n")
    exe.chmod(0o755)
    return prefix


def tree(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def test_dry_run_prints_every_action_and_writes_nothing(tmp_path: Path) -> None:
    root = tmp_path / "root"
    root.mkdir()
    out = install("--dry-run", "--user", "pi", "--root", str(root))
    assert out.returncode == 0, out.stderr
    assert tree(root) == []
    for path in EXPECTED:
        assert f"would write {path}" in out.stdout
    assert "would create /var/lib/lupin" in out.stdout
    for cmd in (
        "systemctl daemon-reload",
        "systemctl enable lupin.service",
        "udevadm control --reload-rules",
    ):
        assert f"would run: {cmd}" in out.stdout


def test_dry_run_on_the_real_root_touches_nothing() -> None:
    unit = Path("/etc/systemd/system/lupin.service")
    before = unit.exists()
    out = install("--dry-run", "--user", "pi")
    assert out.returncode == 0, out.stderr
    assert "would write /etc/systemd/system/lupin.service" in out.stdout
    assert unit.exists() == before


def test_root_install_writes_the_files(tmp_path: Path) -> None:
    root = tmp_path / "root"
    prefix = prefix_with_lupin(tmp_path)
    out = install("--user", "pi", "--prefix", str(prefix), "--root", str(root))
    assert out.returncode == 0, out.stderr
    for path in EXPECTED:
        assert (root / path.lstrip("/")).is_file(), path
    exe = prefix / "bin" / "lupin"

    unit = (root / "etc/systemd/system/lupin.service").read_text()
    assert "User=pi\n" in unit
    assert f"ExecStart={exe} run --config {SITE_CONFIG}\n" in unit
    assert f"ExecStopPost=-{exe} stop-helper --config {SITE_CONFIG}\n" in unit
    assert "/opt/lupin" not in unit

    rule = root / "etc/udev/rules.d" / RULE
    assert rule.read_text() == (source_dir() / RULE).read_text()

    config = root / SITE_CONFIG.lstrip("/")
    assert stat.S_IMODE(config.stat().st_mode) == 0o640
    profile = load_profile(config_file=config)
    assert profile.name == "so101"
    assert profile.bus.port == "/dev/lupin_servos"
    assert profile.api.host == "127.0.0.1"

    assert "export LUPIN_HOME=/var/lib/lupin" in (root / "etc/profile.d/lupin.sh").read_text()
    state = root / "var/lib/lupin"
    assert state.is_dir() and stat.S_IMODE(state.stat().st_mode) == 0o750
    # Commands act on the running system, which --root is not: printed, not run.
    assert "run: systemctl enable lupin.service (skipped: --root" in out.stdout


@pytest.mark.skipif(ANALYZE is None, reason="systemd-analyze is not installed")
def test_the_installed_unit_verifies(tmp_path: Path) -> None:
    root = tmp_path / "root"
    prefix = prefix_with_lupin(tmp_path)
    assert install("--user", "pi", "--prefix", str(prefix), "--root", str(root)).returncode == 0
    assert ANALYZE is not None
    res = subprocess.run(
        [ANALYZE, "verify", "--man=no", str(root / "etc/systemd/system/lupin.service")],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert (res.returncode, res.stdout + res.stderr) == (0, "")


def test_an_edited_site_config_survives_a_reinstall(tmp_path: Path) -> None:
    root = tmp_path / "root"
    prefix = prefix_with_lupin(tmp_path)
    args = ("--user", "pi", "--prefix", str(prefix), "--root", str(root))
    assert install(*args).returncode == 0
    config = root / SITE_CONFIG.lstrip("/")
    config.write_text("profile: mecanum\n")
    out = install(*args, "--profile", "so101")
    assert out.returncode == 0
    assert f"keep {SITE_CONFIG} (exists; not overwritten)" in out.stdout
    assert config.read_text() == "profile: mecanum\n"


def test_refuses_an_unknown_profile_and_a_missing_executable(tmp_path: Path) -> None:
    out = install("--dry-run", "--user", "pi", "--profile", "so100", "--root", str(tmp_path))
    assert out.returncode == 1 and "unknown profile 'so100'" in out.stderr
    out = install("--user", "pi", "--prefix", str(tmp_path / "nope"), "--root", str(tmp_path))
    assert out.returncode == 1 and "not an executable lupin" in out.stderr
    assert tree(tmp_path) == []


def test_refuses_to_run_the_daemon_as_root(tmp_path: Path) -> None:
    out = install("--dry-run", "--user", "root", "--root", str(tmp_path))
    assert out.returncode == 1
    assert "should not run as root" in out.stderr


def test_a_real_install_needs_root(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    assert main(["install-service", "--user", "pi"]) == 1
    assert "needs root" in capsys.readouterr().err


def test_commands_run_in_order_on_a_live_system_and_failures_count() -> None:
    ran: list[tuple[str, ...]] = []

    def fake_run(argv: object) -> int:
        ran.append(tuple(argv))  # type: ignore[arg-type]
        return 1 if "enable" in ran[-1] else 0

    actions = [Command(("systemctl", "daemon-reload")), Command(("systemctl", "enable", "x"))]
    out = io.StringIO()
    assert execute(actions, root=Path("/"), dry_run=False, out=out, run=fake_run) == 1
    assert ran == [("systemctl", "daemon-reload"), ("systemctl", "enable", "x")]
    assert "FAILED: systemctl enable x" in out.getvalue()
