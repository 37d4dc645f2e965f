"""The control law of the 1 kHz loop: a pure function of (config, state, measurements).

``records`` (the one cycle-record layout and the fault bits), ``config`` (the frozen
``controller:`` section), ``ldo`` (discrete disturbance observer and filters),
``feedforward`` (Stribeck friction of the reduced model), ``learned_effects`` (effects
learned by model closure), ``safety`` (the fixed stage after the step), ``step`` (the
composed Numba step) and ``core`` (the Python object the loop, replay and experiments
call).

May import :mod:`capstan.models` only: no devices, no logging, no clocks.
"""
