"""Physics and estimation for the capstan tendon-sheath joint: no device I/O.

Subpackages, lowest first (each may import the ones below it, never above):

- :mod:`capstan.models.common`: the exception hierarchy, config validation helpers,
  the measurement table of the exchange format, the Numba cache placement.
- :mod:`capstan.models.transmission`: routing, pretension field, reduced model,
  baselines, LuGre, the link.
- :mod:`capstan.models.distributed`: the distributed full-order model and its stiff
  integrator.
- :mod:`capstan.models.plant` and :mod:`capstan.models.closure` (independent of each
  other): the simulated rig with injected effects; identification and model closure.

Nothing here imports :mod:`capstan.controller`, :mod:`capstan.drivers` or
:mod:`capstan.tools`.
"""

# Numba cache keyed by the package sources, set before any compiled module is imported
from capstan.models.common.numba_cache import configure_cache as _configure_cache  # noqa: E402

_configure_cache()
