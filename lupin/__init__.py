"""Lupin: one asyncio daemon that owns a small mobile manipulator's Feetech bus.

The core (this package) is pure logic and asyncio tasks. It never imports an
adapter directly; adapters (``lupin_adapters``) are found by name through the
registry in :mod:`lupin.registry`.
"""

__version__ = "0.1.0"
