"""The daemon: read -> step -> write on absolute deadlines.

``config`` (the validated daemon configuration), ``timing`` (deadline sleeping and cycle
statistics), ``realtime`` (scheduling, CPU affinity, memory locking), ``sd_notify``
(systemd readiness and watchdog), ``session_log`` (the daemon's side of the log) and
``daemon`` (devices + controller + log as one process).

May import :mod:`capstan.controller.law`, :mod:`capstan.controller.log`,
:mod:`capstan.drivers` and :mod:`capstan.models`.
"""
