"""Lupin's adapters: I/O at the edges (import name lupin_adapters)."""
