"""The ``capstan`` command line and the offline tools.

- ``cli``: the command table (commands imported lazily).
- :mod:`capstan.tools.commands`: one module per ``capstan`` subcommand.
- :mod:`capstan.tools.experiments`: interaction, end-to-end closure, paper reproduction.
- :mod:`capstan.tools.bench`: benchmarks (scripts that print figures).
- :mod:`capstan.tools.hil`: the simulated rig as its own process, and its hand.
- :mod:`capstan.tools.offline`: loading runs, import descriptions, scenarios, reports,
  plots, progress bars — shared by the above.

``cli`` > ``commands`` > (``experiments`` | ``bench`` | ``hil``) > ``offline``; everything
here may import :mod:`capstan.controller`, :mod:`capstan.drivers` and
:mod:`capstan.models`.
"""

# Numba cache keyed by the package sources, set before any compiled module is imported
from capstan.models.common.numba_cache import configure_cache as _configure_cache  # noqa: E402

_configure_cache()
