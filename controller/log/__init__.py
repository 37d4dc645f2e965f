"""Logging of the 1 kHz loop: never blocks the loop.

``ring`` (preallocated shared-memory record ring), ``schema`` (protobuf schema and codec
derived from a record dtype), ``mcap_writer`` (chunked MCAP writing), ``mcap_log`` (the
log file set: cycles, events, stats, metadata), ``writer`` (the writer process) and
``reader`` (reading a log back).

May import :mod:`capstan.models` only (record layouts arrive as dtypes).
"""
