"""The simulated rig of ``capstan hil`` as its own process: ``plant`` (plant in real time
behind the simulated drive, IMU and load cells) and ``hand`` (a person moving the link).

May import :mod:`capstan.tools.offline` and everything below ``tools``.
"""
