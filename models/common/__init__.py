"""What every layer shares: ``errors`` (the one exception hierarchy), ``config_tools``
(validation of YAML mappings), ``measurement_table`` (the exchange format's CSV +
sidecar), ``numba_cache`` (the Numba cache keyed by the sources) and ``projected_lm`` (a
bounded Levenberg-Marquardt for long output-error fits, Jacobian columns in threads).

Imports nothing from capstan outside this package.
"""
