"""Loading a robot profile: packaged YAML, a site config file, and the measured overlay.

The order is: packaged profile (``config/robots/NAME.yaml``) → optional site config
(``--config FILE``, deep-merged) → ``$LUPIN_HOME/arm.yaml`` (this arm's measured
zero/min/max). The result is validated once, whole, so a zero that the overlay
moves outside its limits is refused like any other mistake. A bad config raises
:class:`ConfigError` naming the file and the field; nothing downstream (and so
no servo) is touched.
"""

from __future__ import annotations

import os
from collections.abc import Hashable, Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from lupin.config_models import ArmOverlay, RobotProfile

DEFAULT_PROFILE = "so101"


class ConfigError(Exception):
    """A configuration file is wrong; the message names the file and the field."""


def lupin_home() -> Path:
    """Per-robot state (calibration, poses): ``$LUPIN_HOME`` or ``~/.lupin``."""
    return Path(os.environ.get("LUPIN_HOME") or Path.home() / ".lupin")


def packaged_profiles() -> list[str]:
    root = resources.files("lupin_config") / "robots"
    return sorted(p.name[:-5] for p in root.iterdir() if p.name.endswith(".yaml"))


class _StrictLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses a key given twice in one mapping.

    PyYAML keeps the last of two equal keys without a word, so a profile with
    ``invert: false`` and, further down, ``invert: true`` loaded whichever came
    last: a silent mistake of the kind unknown keys are refused for. A ``<<``
    merge is not a duplicate: overriding merged keys is what it is for.
    """

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Hashable, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=True)
            try:
                duplicate = key in seen
            except TypeError:
                continue  # an unhashable key: the base class refuses it by name
            if duplicate:
                raise yaml.constructor.ConstructorError(
                    "while constructing a mapping",
                    node.start_mark,
                    f"found duplicate key {key!r}",
                    key_node.start_mark,
                )
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def read_yaml(path: Path | str, text: str | None = None) -> dict[str, Any]:
    """Parse a YAML mapping, turning every failure into a ConfigError naming the file."""
    try:
        if text is None:
            text = Path(path).read_text(encoding="utf-8")
        data = yaml.load(text, Loader=_StrictLoader)  # a SafeLoader: no arbitrary objects
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read: {exc}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from None
    except RecursionError:
        # PyYAML's composer recurses once per nesting level: a few thousand "[" was a
        # traceback instead of a refusal (found by the reliability suite).
        raise ConfigError(f"{path}: not valid YAML: nested too deeply") from None
    except ValueError as exc:
        # Raised while building a value, e.g. an integer of more than 4300 digits
        # (Python's int conversion limit): also a traceback until the reliability suite.
        raise ConfigError(f"{path}: not valid YAML: {exc}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top, got {type(data).__name__}")
    return data


def _profile_source(name: str) -> tuple[str, str | None]:
    """(source, text), text None when the file does not exist."""
    if "/" in name or name.endswith((".yaml", ".yml")):
        path = Path(name)
        # A directory, an unreadable or a binary file was a traceback, and an empty
        # file was reported as missing (found by the reliability suite).
        try:
            return str(path), path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return str(path), None
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{path}: cannot read: {exc}") from None
    res = resources.files("lupin_config") / "robots" / f"{name}.yaml"
    if not res.is_file():
        known = ", ".join(packaged_profiles())
        raise ConfigError(f"unknown profile {name!r} (packaged profiles: {known})")
    return f"config/robots/{name}.yaml", res.read_text(encoding="utf-8")


def deep_merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """Merge mappings recursively; lists and scalars in ``over`` replace those in ``base``."""
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = value
    return out


def format_validation_error(source: str, exc: ValidationError, data: Mapping[str, Any]) -> str:
    lines = []
    for err in exc.errors():
        loc = _format_loc(err["loc"], data)
        msg = str(err["msg"]).removeprefix("Value error, ")
        lines.append(f"{source}: {loc}: {msg}" if loc else f"{source}: {msg}")
    return "\n".join(lines)


def _format_loc(loc: tuple[Any, ...], data: Mapping[str, Any]) -> str:
    out = ""
    node: Any = data
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
            node = node[part] if isinstance(node, list) and part < len(node) else None
            if isinstance(node, Mapping) and isinstance(node.get("name"), str):
                out += f" ({node['name']})"
        else:
            out += f".{part}" if out else str(part)
            node = node.get(part) if isinstance(node, Mapping) else None
    return out


def apply_overlay(data: dict[str, Any], overlay: ArmOverlay, source: str) -> dict[str, Any]:
    arm = data.get("arm", {})
    joints = arm.get("joints", []) if isinstance(arm, Mapping) else None
    if not isinstance(joints, list):
        # The merged profile is malformed here (a site config set ``arm`` or ``arm.joints``
        # to a scalar): that was a traceback, or blamed the overlay. Leave it to validation,
        # which names the field (found by the reliability suite).
        return data
    names = [j.get("name") for j in joints if isinstance(j, Mapping)]
    for name in overlay.joints:
        if name not in names:
            raise ConfigError(f"{source}: joints.{name}: not a joint of this profile ({names})")
    new_joints = []
    for joint in joints:
        jname = joint.get("name") if isinstance(joint, Mapping) else None
        ov = overlay.joints.get(jname) if isinstance(jname, str) else None
        if ov is not None:
            joint = {**joint, "zero": ov.zero, "min": ov.min, "max": ov.max}
        new_joints.append(joint)
    return deep_merge(data, {"arm": {**data.get("arm", {}), "joints": new_joints}})


def load_overlay(path: Path) -> ArmOverlay | None:
    if not path.exists():
        return None
    raw = read_yaml(path)
    try:
        return ArmOverlay.model_validate(raw)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(str(path), exc, raw)) from None


def load_profile(
    profile: str | None = None,
    *,
    config_file: Path | str | None = None,
    home: Path | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> RobotProfile:
    """Load, merge and validate a robot profile. Raises ConfigError on any mistake."""
    site: dict[str, Any] = {}
    if config_file is not None:
        site = read_yaml(config_file)
        site_profile = site.pop("profile", None)
        if site_profile is not None and not isinstance(site_profile, str):
            raise ConfigError(f"{config_file}: profile: expected a profile name")
        profile = profile or site_profile
    source, text = _profile_source(profile or DEFAULT_PROFILE)
    if text is None:
        raise ConfigError(f"{source}: no such file")
    data = read_yaml(source, text)
    sources = [source]
    if site:
        data = deep_merge(data, site)
        sources.append(str(config_file))
    if overrides:
        data = deep_merge(data, overrides)
    overlay_path = (home or lupin_home()) / "arm.yaml"
    overlay = load_overlay(overlay_path)
    if overlay is not None:
        data = apply_overlay(data, overlay, str(overlay_path))
        sources.append(str(overlay_path))
    try:
        return RobotProfile.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(" + ".join(sources), exc, data)) from None
