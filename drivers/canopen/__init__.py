"""The motor role on a CiA 402 servo drive over CANopen (the ``canopen`` stack).

``cia402`` (the state machine as a transition table), ``emcy`` (EMCY frames decoded),
``config`` (the ``motor:`` section and the shipped EDS in ``data/``), ``drive_setup``
(SDO start-up configuration) and ``motor`` (the :class:`~capstan.drivers.interfaces.Motor`
implementation on PDOs).

May import :mod:`capstan.drivers.interfaces` and :mod:`capstan.models`.
"""
