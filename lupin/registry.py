"""Adapters by name: built-ins plus the ``lupin.bus`` / ``lupin.joystick`` entry-point groups.

The core never imports an adapter module directly (python-can's BACKENDS
pattern): it asks here for ``"module:attr"`` by name and imports on demand, so a
missing ``hidapi`` or ``evdev`` breaks only its own adapter, and a third-party
package adds one by declaring an entry point, with no edit to the core.
"""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points
from typing import Any

BUILTIN: dict[str, dict[str, str]] = {
    "lupin.bus": {
        "serial": "lupin_adapters.serial_link:open_link",
        "sim": "lupin_adapters.sim.link:open_link",
    },
    "lupin.joystick": {
        "evdev": "lupin_adapters.pads.evdev_reader:EvdevReader",
        "hid": "lupin_adapters.pads.hid_reader:HidReader",
        "replay": "lupin_adapters.pads.replay:ReplayReader",
    },
}


class AdapterNotFound(LookupError):
    pass


def available(group: str) -> dict[str, str]:
    found = dict(BUILTIN.get(group, {}))
    for ep in entry_points(group=group):
        found[ep.name] = ep.value
    return found


def load(group: str, name: str) -> Any:
    """Import and return the adapter ``name`` of ``group``; a clear error if unknown."""
    target = available(group).get(name)
    if target is None:
        known = ", ".join(sorted(available(group))) or "none"
        raise AdapterNotFound(f"no {group} adapter named {name!r} (known: {known})")
    module_name, _, attr = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise AdapterNotFound(f"{group} adapter {name!r} cannot be loaded: {exc}") from exc
    return getattr(module, attr)
