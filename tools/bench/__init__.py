"""Benchmarks: scripts that print figures, run on demand (``python -m
capstan.tools.bench.<name>``), never timed unit tests.

May import :mod:`capstan.tools.offline` and everything below ``tools``.
"""
