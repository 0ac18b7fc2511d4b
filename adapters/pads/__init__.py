"""Pad readers (the ``lupin.joystick`` entry-point group): evdev, hidapi (DS4), replay.

Each module imports its library lazily, inside the reader, so a machine without
``hidapi`` or ``evdev`` loses only that reader. Every reader yields
:class:`lupin.pad.PadFrame` snapshots in joy_node's index order for its layout,
and ``None`` when the pad vanishes.
"""
