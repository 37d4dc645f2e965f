"""Serial devices: the Xsens MTi (MT binary protocol) and the load-cell amplifier.

``xbus`` (Xbus framing), ``xsens_protocol`` (MTData2 decoding), ``xsens`` (the IMU role),
``loadcell_protocol`` (the amplifier's frame), ``loadcell`` (the load-cell role) and
``port_io`` (non-blocking reads from a pyserial port).

May import :mod:`capstan.drivers.interfaces` and :mod:`capstan.models`.
"""
