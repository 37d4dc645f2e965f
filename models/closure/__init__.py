"""Identification and model closure: fit, residual, trace, missing effects.

``signals`` (candidate signals of a run), ``baseline_shape`` and ``identification`` (the
baseline fit), ``effects`` (the catalogue of missing effects), ``augmented`` (baseline +
effects as one model), ``residual_trace`` (signal attribution), ``pipeline`` (the
closure itself) and ``effects_runtime`` (learned effects in the controller's format);
:mod:`.dynamic`: the dynamic baseline (the reduced model simulated through each run) and the
effects inside it; ``windows`` and ``dynamic.long_run``: the closure of long runs (fits started
on contiguous windows, finished on every sample).

May import :mod:`capstan.models.distributed`, :mod:`capstan.models.transmission` and
:mod:`capstan.models.common`; not :mod:`capstan.models.plant` (a fit must not know the
simulator that produced its data).
"""
