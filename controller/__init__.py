"""The real-time part of capstan: discrete LDO, friction feedforward, safety stage
(Numba step functions on preallocated arrays), the 1 kHz loop and the daemon."""

# Numba cache keyed by the package sources, set before any compiled module is imported
from models.numba_cache import configure_cache as _configure_cache  # noqa: E402

_configure_cache()
