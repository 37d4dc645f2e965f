"""Simulated devices that speak the real wire protocols (the HIL backends).

``drive`` (a CiA 402 drive as a CANopen slave) and ``serial_devices`` (an Xsens MTi and
the load-cell amplifier on pseudo-terminals).

May import :mod:`capstan.drivers.canopen`, :mod:`capstan.drivers.serial`,
:mod:`capstan.drivers.interfaces` and :mod:`capstan.models`.
"""
