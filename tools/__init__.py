"""Offline tools and the ``capstan`` command line: simulate, replay, export,
identify, close the model loop, experiments and benchmarks."""

# Numba cache keyed by the package sources, set before any compiled module is imported
from models.numba_cache import configure_cache as _configure_cache  # noqa: E402

_configure_cache()
