"""``lupin install-service``: put Lupin on a Raspberry Pi OS robot as a systemd service.

It installs ``systemd/lupin.service`` (User= and the lupin executable filled
in), the udev rule that names the bus ``/dev/lupin_servos``, a site config
``/etc/lupin/lupin.yaml`` if there is none, ``/etc/profile.d/lupin.sh`` so the
bench tools use the service's ``$LUPIN_HOME``, and the state directory; then it
adds the user to dialout/input and runs daemon-reload, enable and a udev reload.

Everything is planned first as a list of actions: ``--dry-run`` prints them and
writes nothing; ``--root DIR`` writes the files under DIR (for tests and image
builds) and leaves the running system alone (no commands, no chown).
"""

from __future__ import annotations

import argparse
import grp
import os
import pwd
import re
import shutil
import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from lupin.config import packaged_profiles

UNIT = "lupin.service"
RULE = "99-lupin-servos.rules"
TEMPLATE_EXE = "/opt/lupin/bin/lupin"  # what the repo's unit says, rewritten on install
UNIT_DIR = "/etc/systemd/system"
RULES_DIR = "/etc/udev/rules.d"
SITE_CONFIG = "/etc/lupin/lupin.yaml"
PROFILE_SH = "/etc/profile.d/lupin.sh"
STATE_DIR = "/var/lib/lupin"  # StateDirectory=lupin; LUPIN_HOME=%S/lupin
GROUPS = ("dialout", "input")


class InstallError(Exception):
    """Something the operator must fix before anything is installed."""


@dataclass(frozen=True)
class WriteFile:
    path: str  # absolute, on the target system
    text: str
    mode: int = 0o644
    keep_existing: bool = False  # an operator's edits win (the site config)
    group_of: str | None = None  # readable by this user's group (the config may hold a token)


@dataclass(frozen=True)
class MakeDir:
    path: str
    mode: int
    owner: str  # chown on a real install


@dataclass(frozen=True)
class Command:
    argv: tuple[str, ...]


Action = WriteFile | MakeDir | Command


def source_dir() -> Path:
    """The repo's ``systemd/`` folder (the unit and rule ship there, beside the package)."""
    here = Path(__file__).resolve().parents[2] / "systemd"
    if not (here / UNIT).is_file():
        raise InstallError(
            f"cannot find {UNIT} in {here}: install Lupin from its source tree "
            "(pip install -e .) so the systemd/ folder is there"
        )
    return here


def render_unit(template: str, exe: str, user: str) -> str:
    """The unit with the real executable and user in place of the template's."""
    text = template.replace(TEMPLATE_EXE, exe)
    return re.sub(r"^User=.*$", f"User={user}", text, count=1, flags=re.MULTILINE)


def site_config(profile: str) -> str:
    return f"""\
# Lupin site config, merged over the packaged profile (docs/configuration.md).
# Read by lupin.service (lupin run --config {SITE_CONFIG}) and by its
# ExecStopPost stop helper, so both drive the same bus and the same servos.
profile: {profile}
bus:
  port: /dev/lupin_servos   # the stable name from {RULES_DIR}/{RULE}
api:
  host: 127.0.0.1           # the HMI on the robot only; set api.token before widening
  port: 8080
"""


def profile_sh() -> str:
    return f"""\
# Lupin: bench tools (lupin calibrate, offsets, gains, ...) read and write the
# same calibration and poses as the service (StateDirectory=lupin).
export LUPIN_HOME={STATE_DIR}
"""


def find_exe(prefix: str | None) -> str:
    """The lupin console script to put in ExecStart (absolute; symlinks kept)."""
    if prefix is not None:
        return str(Path(prefix).absolute() / "bin" / "lupin")
    candidates = [Path(sys.prefix) / "bin" / "lupin", Path(sys.executable).parent / "lupin"]
    which = shutil.which("lupin")
    if which:
        candidates.append(Path(which))
    for path in candidates:
        if path.is_file() and os.access(path, os.X_OK):
            return str(path.absolute())
    raise InstallError(
        "cannot find the lupin executable; pass --prefix (the venv holding bin/lupin)"
    )


def find_user(user: str | None) -> str:
    name = user or os.environ.get("SUDO_USER") or (pwd.getpwuid(os.getuid()).pw_name)
    if name == "root":
        raise InstallError("pass --user USER: the daemon should not run as root")
    return name


def plan(*, exe: str, user: str, profile: str, units: Path) -> list[Action]:
    """Every action of an install, in order; nothing is touched here."""
    unit = render_unit((units / UNIT).read_text(encoding="utf-8"), exe, user)
    actions: list[Action] = [
        WriteFile(f"{UNIT_DIR}/{UNIT}", unit),
        WriteFile(f"{RULES_DIR}/{RULE}", (units / RULE).read_text(encoding="utf-8")),
        WriteFile(SITE_CONFIG, site_config(profile), 0o640, keep_existing=True, group_of=user),
        WriteFile(PROFILE_SH, profile_sh()),
        MakeDir(STATE_DIR, 0o750, owner=user),
    ]
    missing = [g for g in GROUPS if not _in_group(user, g)]
    if missing:
        actions.append(Command(("usermod", "-aG", ",".join(missing), user)))
    actions += [
        Command(("systemctl", "daemon-reload")),
        Command(("systemctl", "enable", UNIT)),
        Command(("udevadm", "control", "--reload-rules")),
        # An adapter plugged in already gets its /dev/lupin_servos now, not at next plug.
        Command(("udevadm", "trigger", "--subsystem-match=tty", "--action=add")),
    ]
    return actions


def _in_group(user: str, group: str) -> bool:
    try:
        g = grp.getgrnam(group)
    except KeyError:
        return False
    try:
        primary = pwd.getpwnam(user).pw_gid
    except KeyError:
        primary = -1
    return user in g.gr_mem or g.gr_gid == primary


Runner = Callable[[Sequence[str]], int]


def _run(argv: Sequence[str]) -> int:
    return subprocess.run(list(argv), check=False).returncode


def execute(
    actions: list[Action], *, root: Path, dry_run: bool, out: TextIO, run: Runner = _run
) -> int:
    """Carry out (or, dry, describe) each action; the number of failed commands."""
    live = root == Path("/")
    would = "would " if dry_run else ""
    failures = 0
    for action in actions:
        if isinstance(action, Command):
            cmd = " ".join(action.argv)
            if dry_run or not live:
                note = "" if dry_run else f" (skipped: --root {root} is not the running system)"
                print(f"{would}run: {cmd}{note}", file=out)
                continue
            print(f"run: {cmd}", file=out)
            if run(action.argv) != 0:
                print(f"  FAILED: {cmd}", file=out)
                failures += 1
            continue
        target = root / action.path.lstrip("/")
        if isinstance(action, MakeDir):
            print(
                f"{would}create {action.path} (mode {action.mode:o}, owner {action.owner})",
                file=out,
            )
            if not dry_run:
                target.mkdir(parents=True, exist_ok=True)
                target.chmod(action.mode)
                if live:
                    shutil.chown(target, action.owner, pwd.getpwnam(action.owner).pw_gid)
            continue
        if action.keep_existing and target.exists():
            print(f"{would}keep {action.path} (exists; not overwritten)", file=out)
            continue
        print(f"{would}write {action.path} (mode {action.mode:o})", file=out)
        if not dry_run:
            target.parent.mkdir(parents=True, exist_ok=True)
            tmp = target.with_name(f".{target.name}.tmp")
            tmp.write_text(action.text, encoding="utf-8")
            tmp.chmod(action.mode)
            if live and action.group_of is not None:
                shutil.chown(tmp, "root", pwd.getpwnam(action.group_of).pw_gid)
            tmp.replace(target)  # atomic: systemd never reads half a unit
    return failures


def main(args: argparse.Namespace) -> int:
    root = Path(args.root).absolute()
    live = root == Path("/")
    try:
        if live and not args.dry_run and os.geteuid() != 0:
            raise InstallError("installing into / needs root: run it with sudo (or --dry-run)")
        user = find_user(args.user)
        if live and not args.dry_run:
            try:
                pwd.getpwnam(user)
            except KeyError:
                raise InstallError(f"no such user {user!r}; pass --user") from None
        exe = find_exe(args.prefix)
        if not args.dry_run and not os.access(exe, os.X_OK):
            raise InstallError(f"{exe} is not an executable lupin; check --prefix")
        if args.profile not in packaged_profiles() and not Path(args.profile).is_file():
            known = ", ".join(packaged_profiles())
            raise InstallError(f"unknown profile {args.profile!r} (packaged: {known})")
        actions = plan(exe=exe, user=user, profile=args.profile, units=source_dir())
    except InstallError as exc:
        print(f"lupin install-service: {exc}", file=sys.stderr)
        return 1
    doing = "Would install" if args.dry_run else "Installing"
    print(f"{doing} Lupin for user {user}, running {exe}", file=sys.stdout)
    failures = execute(actions, root=root, dry_run=args.dry_run, out=sys.stdout)
    _next_steps(user, dry_run=args.dry_run)
    return 1 if failures else 0


def _next_steps(user: str, *, dry_run: bool) -> None:
    home = Path(pwd.getpwnam(user).pw_dir) / ".lupin" if _has_user(user) else None
    if home is not None and (home / "arm.yaml").exists():
        print(
            f"note: {home}/arm.yaml holds a calibration; the service reads {STATE_DIR}: "
            f"copy it there (cp {home}/*.yaml {STATE_DIR}/)"
        )
    if not dry_run:
        print("next: sudo systemctl start lupin; journalctl -u lupin -f (docs/operations.md)")
        print(f"      log in again for {user}'s new groups to apply to the bench tools")


def _has_user(user: str) -> bool:
    try:
        pwd.getpwnam(user)
    except KeyError:
        return False
    return True
