"""Shared test support: harnesses for the simulated bus and the real daemon."""
