"""Shared pieces of the offline tools: ``run_inputs`` (load runs from tables or logs),
``importer`` (import descriptions of other layouts), ``scenario`` (testbed scenario
files), ``closure_report`` (closure report and controller fragment), ``plots`` and
``progress``.

May import :mod:`capstan.controller`, :mod:`capstan.drivers` and :mod:`capstan.models`;
no other ``capstan.tools`` subpackage.
"""
