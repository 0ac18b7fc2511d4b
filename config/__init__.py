"""Packaged configuration data (import name ``lupin_config``): robot profiles and pad mappings."""
