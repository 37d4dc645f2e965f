"""Learned effects for the controller: the config fragment format and an njit
evaluation of each effect's torque.

Fragment (written by ``capstan close``, loaded by the controller's feedforward)::

    controller:
      feedforward:
        effects:
          - effect: dwell_stiction          # catalogue name (models.effects) or "empirical"
            code: 1                         # EffectCode below
            depends_on: [dwell]
            params: {amp_Nm: 1.2, tau_age_s: 1.0, s0_rad: 0.03}
            p: [1.2, 1.0, 0.03, 0, 0, 0, 0, 0]        # packed params, layout per code (below)
            # empirical effects also carry knots / even / odd (same length)
        effects_shape: {alpha_s_rad: 30.0, eta_s_rad_s: 0.05, zeta_s: 1.3, v_rest_rad_s: 0.01}
    identification:                         # the baseline the effects were fitted on
      model: reduced
      params: {...}
      stderr: {...}

Each effect is an extra transmission loss ``tau_e`` [Nm]; the feedforward adds it to
the torque reference (``tau_in,des += sum tau_e``). ``s(dq)`` is the friction shape
``tanh(alpha dq) (1 + (zeta_s - 1) exp(-(dq/eta_s)^2))`` of ``effects_shape``.

Packed layouts ``p`` (8 floats):

=====  =====================  ================================================
code   effect                 p
=====  =====================  ================================================
1      dwell_stiction         amp_Nm, tau_age_s, s0_rad
2      speed_viscous          c2_Nms2_rad2, c3_Nms3_rad3
3      position_friction      a1_Nm_rad, a2_Nm_rad2, q_ref_rad
4      pretension_relaxation  d_Nm, tau_r_s
5      load_friction          c_load
6      temperature_drift      ct_Nm_K, co_Nm_K, T_ref   (aux = temperature)
7      tension_friction       c_Nm_N, T_ref             (aux = mean tension)
8      output_inertia         J_kg_m2
9      empirical              signal code (0 dq, 1 ddq, 2 q, 3 rest, 4 time, 5 load, 6 aux)
0      informational          (sensor_latency: lag_s; nonlinear_stiffness: K3) -> 0 Nm
=====  =====================  ================================================

The dwell inputs (``rest_s``: duration of the rest before the current motion, or the
rest so far; ``slide_rad``: angle since motion onset) come from
:func:`capstan.models.closure.signals.dwell_states` logic; :func:`dwell_update` is its one-sample
njit form for the 1 kHz loop.
"""

from __future__ import annotations

import math
from enum import IntEnum
from typing import Any, Mapping, Sequence

import numpy as np
from numba import njit

from capstan.models.common.errors import ConfigError

N_P = 8


class EffectCode(IntEnum):
    """Packed effect kinds of the fragment (see module table)."""

    INFO = 0
    DWELL_STICTION = 1
    SPEED_VISCOUS = 2
    POSITION_FRICTION = 3
    PRETENSION_RELAXATION = 4
    LOAD_FRICTION = 5
    TEMPERATURE_DRIFT = 6
    TENSION_FRICTION = 7
    OUTPUT_INERTIA = 8
    EMPIRICAL = 9


_SIGNAL_CODES = {"velocity": 0, "acceleration": 1, "position": 2, "dwell": 3, "time": 4, "load": 5}


@njit(cache=True)
def friction_shape(dq_rad_s: float, alpha_s_rad: float, eta_s_rad_s: float, zeta_s: float) -> float:
    """s(dq) = tanh(alpha dq) (1 + (zeta_s - 1) exp(-(dq/eta_s)^2)) [-]."""
    x = dq_rad_s / eta_s_rad_s
    return math.tanh(alpha_s_rad * dq_rad_s) * (1.0 + (zeta_s - 1.0) * math.exp(-x * x))


@njit(cache=True)
def effect_loss_Nm(code: int, p: np.ndarray, knots: np.ndarray, even: np.ndarray, odd: np.ndarray,
                   s: float, dq_rad_s: float, ddq_rad_s2: float, q_rad: float, rest_s: float, slide_rad: float,
                   time_s: float, load_Nm: float, aux: float) -> float:
    """Extra transmission loss of one effect [Nm] (positive = like friction in +dq)."""
    if code == 1:
        return p[0] * s * (1.0 - math.exp(-rest_s / p[1])) * math.exp(-slide_rad / p[2])
    if code == 2:
        return p[0] * dq_rad_s * abs(dq_rad_s) + p[1] * dq_rad_s ** 3
    if code == 3:
        d = q_rad - p[2]
        return s * (p[0] * d + p[1] * d * d)
    if code == 4:
        return p[0] * s * (1.0 - math.exp(-time_s / p[1]))
    if code == 5:
        return p[0] * s * abs(load_Nm)
    if code == 6:
        return (p[0] * s + p[1]) * (aux - p[2])
    if code == 7:
        return p[0] * s * (aux - p[1])
    if code == 8:
        return p[0] * ddq_rad_s2
    if code == 9:
        sig = int(p[0])
        x = dq_rad_s
        if sig == 1:
            x = ddq_rad_s2
        elif sig == 2:
            x = q_rad
        elif sig == 3:
            x = rest_s
        elif sig == 4:
            x = time_s
        elif sig == 5:
            x = load_Nm
        elif sig == 6:
            x = aux
        # the closure fitted the residual contribution r = f(x) + s g(x); the loss is -r
        return -(np.interp(x, knots, even) + s * np.interp(x, knots, odd))
    return 0.0


@njit(cache=True)
def total_effect_loss_Nm(codes: np.ndarray, P: np.ndarray, K: np.ndarray, E: np.ndarray, O: np.ndarray,
                         n_knots: np.ndarray, shape: np.ndarray, dq_rad_s: float, ddq_rad_s2: float,
                         q_rad: float, rest_s: float, slide_rad: float, time_s: float, load_Nm: float,
                         aux: np.ndarray) -> float:
    """Sum of all learned effects [Nm]; arrays from :func:`pack_effects`, ``aux[i]`` per effect."""
    s = friction_shape(dq_rad_s, shape[0], shape[1], shape[2])
    tot = 0.0
    for i in range(codes.shape[0]):
        k = n_knots[i]
        tot += effect_loss_Nm(codes[i], P[i], K[i, :k], E[i, :k], O[i, :k], s, dq_rad_s, ddq_rad_s2, q_rad,
                              rest_s, slide_rad, time_s, load_Nm, aux[i])
    return tot


@njit(cache=True)
def dwell_update(state: np.ndarray, dq_rad_s: float, dt_s: float, v_rest_rad_s: float) -> None:
    """One sample of the dwell bookkeeping; ``state`` = [speed, moving, dwell_s, rest_s, slide_rad]
    (initialise to [0, 0, 10, 10, 0]); same rule as :func:`capstan.models.closure.signals.dwell_states`."""
    a = min(1.0, dt_s / 0.02)
    state[0] += a * (abs(dq_rad_s) - state[0])
    if state[1] > 0.5 and state[0] < v_rest_rad_s:
        state[1] = 0.0
    elif state[1] < 0.5 and state[0] > 2.0 * v_rest_rad_s:
        state[1] = 1.0
    if state[1] < 0.5:
        state[2] += dt_s
        state[3] = state[2]
        state[4] = 0.0
    else:
        if state[2] > 0.0:
            state[3] = state[2]
        state[2] = 0.0
        state[4] += abs(dq_rad_s) * dt_s


def pack_effects(effects: Sequence[Mapping[str, Any]], prefix: str = "controller.feedforward.effects"
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pack the fragment's effect list for :func:`total_effect_loss_Nm`.

    Returns ``(codes, P, K, E, O, n_knots)``.

    :raises ConfigError: naming the entry and key on a malformed effect.
    """
    m = len(effects)
    kmax = max([len(e.get("knots", [])) for e in effects] + [2])
    codes = np.zeros(m, np.int64)
    P = np.zeros((m, N_P))
    K = np.zeros((m, kmax))
    E = np.zeros((m, kmax))
    O = np.zeros((m, kmax))
    nk = np.full(m, 2, np.int64)
    K[:, 1] = 1.0
    for i, e in enumerate(effects):
        key = f"{prefix}[{i}]"
        if not isinstance(e, Mapping):
            raise ConfigError(key, "must be a mapping with effect, code, p")
        code = e.get("code")
        if not isinstance(code, int) or code not in [c.value for c in EffectCode]:
            raise ConfigError(f"{key}.code", f"must be one of {[c.value for c in EffectCode]}, got {code!r}")
        p = e.get("p", [])
        if not isinstance(p, list) or len(p) != N_P or not all(isinstance(x, (int, float)) for x in p):
            raise ConfigError(f"{key}.p", f"must be a list of {N_P} numbers, got {p!r}")
        codes[i] = code
        P[i] = p
        if code == EffectCode.EMPIRICAL:
            kn, ev, od = e.get("knots"), e.get("even"), e.get("odd")
            if not (isinstance(kn, list) and isinstance(ev, list) and isinstance(od, list)
                    and len(kn) == len(ev) == len(od) >= 2):
                raise ConfigError(f"{key}.knots", "empirical effects need knots, even, odd of equal length >= 2")
            if not np.all(np.diff(kn) > 0):
                raise ConfigError(f"{key}.knots", "must be strictly increasing")
            nk[i] = len(kn)
            K[i, :len(kn)], E[i, :len(kn)], O[i, :len(kn)] = kn, ev, od
    return codes, P, K, E, O, nk


def signal_code(name: str) -> int:
    """Empirical-effect input code of a signal name (6 = the effect's aux channel)."""
    return _SIGNAL_CODES.get(name, 6)
