"""Device drivers and the simulated devices that speak the same wire protocols.

Top level: ``interfaces`` (one narrow interface per device role), ``registry`` (config
key -> backend, imported lazily) and ``can_unix`` (a cross-process python-can bus).

- :mod:`capstan.drivers.canopen`: the motor role on a CiA 402 drive over CANopen.
- :mod:`capstan.drivers.serial`: the Xsens MTi and the load-cell amplifier on serial ports.
- :mod:`capstan.drivers.sim`: simulated drive, IMU and amplifier (the HIL backends).

``canopen`` and ``serial`` are independent of each other; ``sim`` may import both (it
speaks their protocols). Everything here may import :mod:`capstan.models`; nothing here
imports :mod:`capstan.controller` or :mod:`capstan.tools`.
"""

# Numba cache keyed by the package sources, set before any compiled module is imported
from capstan.models.common.numba_cache import configure_cache as _configure_cache  # noqa: E402

_configure_cache()
