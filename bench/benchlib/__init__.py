"""Shared pieces of the benchmarks in ``bench/``: statistics, processes, metrics, the pad feed.

The benchmark scripts run as ``python bench/NAME.py``, so ``bench/`` is on
``sys.path`` and this package imports as ``benchlib``.
"""
