"""The physics of the friction effects injected into simulated plants, shared by the
simulated testbed (:mod:`capstan.models.plant.effect_plant`) and the simulated rig
(:mod:`capstan.models.plant.rig_effects`, used by the hardware-in-the-loop plant).

Each effect scales the transmission's friction (tau_fc, or mu of every sheath node in
the distributed model) by a multiplier ``m`` computed from the plant's true state
between integration steps. ``kind`` is the effect's index in
:data:`capstan.models.plant.effect_plant.INJECTABLE`:

====  =====================  =============================================================
kind  effect                 m
====  =====================  =============================================================
1     dwell_stiction         1 + A (1 - exp(-rest/tau_age)) exp(-slide/s0)
3     position_friction      1 + a1 q + a2 q^2
4     pretension_relaxation  1 - d (1 - exp(-t/tau_r))
7     load_friction          1 + c |tau_in|
8     temperature_drift      1 + c (T - 25 degC)
9     friction_ripple        1 + A sin(2 pi q / P)
====  =====================  =============================================================

Other kinds return 1. ``rest`` / ``slide`` follow :func:`plant_dwell_step` on the true
output velocity: the joint rests while ``|dq| < v_rest``; ``rest`` is the duration of the
last rest (or the rest so far), ``slide`` the angle slid since motion onset.
"""

from __future__ import annotations

import math

from numba import njit

#: rest threshold of the plants' dwell bookkeeping on the true output velocity [rad/s]
PLANT_V_REST_RAD_S = 0.02

KIND_DWELL_STICTION = 1
KIND_POSITION_FRICTION = 3
KIND_PRETENSION_RELAXATION = 4
KIND_LOAD_FRICTION = 7
KIND_TEMPERATURE_DRIFT = 8
KIND_FRICTION_RIPPLE = 9


@njit(cache=True)
def friction_multiplier(kind: int, p0: float, p1: float, p2: float, q_rad: float, rest_s: float,
                        slide_rad: float, t_s: float, load_Nm: float, temperature_degC: float) -> float:
    """Friction multiplier ``m`` [-] of one injected effect (module table); ``load_Nm`` is
    the input torque, ``temperature_degC`` the temperature channel."""
    m = 1.0
    if kind == 1:
        m = 1.0 + p0 * (1.0 - math.exp(-rest_s / p1)) * math.exp(-slide_rad / p2)
    elif kind == 3:
        m = 1.0 + p0 * q_rad + p1 * q_rad * q_rad
    elif kind == 4:
        m = 1.0 - p0 * (1.0 - math.exp(-t_s / p1))
    elif kind == 7:
        m = 1.0 + p0 * abs(load_Nm)
    elif kind == 8:
        m = 1.0 + p0 * (temperature_degC - 25.0)
    elif kind == 9:
        m = 1.0 + p0 * math.sin(2.0 * math.pi * q_rad / p1)
    return m


@njit(cache=True)
def plant_dwell_step(dwell_s: float, rest_s: float, slide_rad: float, dq_rad_s: float, dt_s: float,
                     v_rest_rad_s: float) -> tuple[float, float, float]:
    """One step of the plant's dwell bookkeeping; returns ``(dwell_s, rest_s, slide_rad)``.

    ``dwell_s``: time since the joint last moved (0 while moving); ``rest_s``: duration of
    the rest before the current motion (while resting: the rest so far); ``slide_rad``:
    angle slid since motion onset. Start from ``(10, 10, 0)`` (a long rest before the run).
    """
    if abs(dq_rad_s) < v_rest_rad_s:
        dwell_s += dt_s
        rest_s = dwell_s
        slide_rad = 0.0
    else:
        if dwell_s > 0.0:
            rest_s = dwell_s
        dwell_s = 0.0
        slide_rad += abs(dq_rad_s) * dt_s
    return dwell_s, rest_s, slide_rad
