"""Device drivers (CiA 402 motor over CANopen, Xsens MTi IMU, load-cell amplifier)
and simulated devices that speak the same wire protocols."""

# Numba cache keyed by the package sources, set before any compiled module is imported
from models.numba_cache import configure_cache as _configure_cache  # noqa: E402

_configure_cache()
