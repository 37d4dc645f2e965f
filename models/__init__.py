"""Physics and estimation for the capstan tendon-sheath joint: no I/O here (but for
``numba_cache``, which places the Numba cache by a fingerprint of the sources).

Routing and pretension, the distributed full-order model, the reduced model and
baselines, the simulated rig, the effect catalogue and identification math.
"""

# Numba cache keyed by the package sources, set before any compiled module is imported
from models.numba_cache import configure_cache as _configure_cache  # noqa: E402

_configure_cache()
