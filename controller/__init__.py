"""The real-time part of capstan.

Subpackages (arrows are the only imports allowed, enforced by the import contract in
``pyproject.toml``, ``[tool.importlinter]``):

- :mod:`capstan.controller.law`: the control law — record layout, LDO, friction
  feedforward, learned effects, safety stage, the composed Numba step and the
  Python-facing :class:`~capstan.controller.law.core.Controller`. Pure: no I/O, no
  devices, no clocks. May import :mod:`capstan.models`.
- :mod:`capstan.controller.log`: the shared-memory record ring, the MCAP writer process
  and the log reader. May import :mod:`capstan.models`.
- :mod:`capstan.controller.runtime`: the daemon — configuration, the 1 kHz loop on
  absolute deadlines, real-time setup, systemd notification, the log session. May
  import ``law``, ``log``, :mod:`capstan.drivers` and :mod:`capstan.models`.

Nothing here imports :mod:`capstan.tools`.
"""

# Numba cache keyed by the package sources, set before any compiled module is imported
from capstan.models.common.numba_cache import configure_cache as _configure_cache  # noqa: E402

_configure_cache()
