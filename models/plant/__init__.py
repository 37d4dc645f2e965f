"""The simulated plant: what stands in for the hardware.

``config`` (plant from a YAML mapping), ``rig`` (motor + distributed transmission +
output), ``sensors``, ``drive_feedback`` and ``command_path`` (what the rig's devices report
and how commands reach its motor: realistic by default, ideal on request), ``rig_effects`` and ``injected_friction`` (effects injected into the rig),
``effect_plant`` (reduced-family testbed runs with an injected effect, for unit tests of
the fitting code) and ``excitation`` (input-torque excitations).

May import :mod:`capstan.models.distributed`, :mod:`capstan.models.transmission` and
:mod:`capstan.models.common`; not :mod:`capstan.models.closure`.
"""
