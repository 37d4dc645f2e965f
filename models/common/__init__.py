"""What every layer shares: ``errors`` (the one exception hierarchy), ``config_tools``
(validation of YAML mappings), ``measurement_table`` (the exchange format's CSV +
sidecar) and ``numba_cache`` (the Numba cache keyed by the sources).

Imports nothing from capstan outside this package.
"""
