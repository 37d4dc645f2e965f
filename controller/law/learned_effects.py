"""Learned transmission effects in the 1 kHz step: the ``controller.feedforward.effects``
fragment written by ``capstan close`` (format and per-effect torque:
:mod:`capstan.models.closure.effects_runtime`).

Each effect is an extra transmission loss ``tau_e`` [Nm] the baseline friction law lacks;
the feedforward adds the sum to its friction torque (so ``gain`` and ``placement`` apply
to it as to eq 21). It is evaluated on every new IMU sample, like eq (21), from:

* ``dq`` / ``q``: the IMU rate of turn and angle; ``ddq``: the difference of successive
  rates, low-passed with a 25 ms time constant;
* ``rest`` / ``slide``: :func:`capstan.models.closure.effects_runtime.dwell_update` (the closure's rule:
  speed smoothed over 20 ms, rest below ``v_rest``, moving again above twice it);
* ``time``: since the first IMU sample the step saw; ``load``: the input torque the step
  asks for *without* the effects, ``(r_in/r_out)(tau_g + tau_out_ref + eq 21)``. The
  measured ``tau_in`` would close an algebraic loop (the effect changes the reference the
  torque loop makes ``tau_in`` follow): a learned slope of ``tau_e`` in the load above 1
  would be positive feedback. In steady tracking the two agree;
* ``aux``: the mean measured cable tension for ``tension_friction``. Effects on other
  channels (temperature) cannot be evaluated here and are refused at configuration.

The fragment is packed once (:func:`pack_block`) into the tail of the step's config
array, so the step keeps its signature and stays allocation-free. Layout from offset
``off`` (:data:`capstan.controller.law.step.N_CFG`)::

    [n, alpha_s, eta_s, zeta_s, v_rest, kmax,
     per effect: code, aux (0 none, 1 tension), n_knots, p[8], knots[kmax], even[kmax], odd[kmax]]

State (:data:`N_FX_STATE` floats from ``s``): init flag, the five dwell states, time and
rate of the previous IMU sample, filtered acceleration, time of the first sample.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np
from numba import njit

from capstan.models.closure.effects_runtime import N_P, dwell_update, effect_loss_Nm, friction_shape, pack_effects
from capstan.models.common.errors import ConfigError

B_N, B_ALPHA, B_ETA, B_ZETA, B_V_REST, B_KMAX = range(6)
B_HEAD = 6
E_CODE, E_AUX, E_NK, E_P = 0, 1, 2, 3
AUX_NONE, AUX_TENSION = 0, 1

F_INIT, F_DWELL, F_T_PREV, F_DQ_PREV, F_DDQ, F_T0 = 0, 1, 6, 7, 8, 9
N_FX_STATE = 10

#: time constant of the acceleration low-pass [s]
DDQ_TAU_S = 0.025

#: keys an effect entry may carry (the fragment of tools.closure_report)
ENTRY_KEYS = frozenset({"effect", "code", "depends_on", "params", "p", "knots", "even", "odd", "aux"})


def check_entries(effects: Any, prefix: str) -> tuple[dict[str, Any], ...]:
    """Validate the fragment's effect list; returns plain copies of the entries.

    :raises ConfigError: naming the entry and key (unknown key, malformed packing, or an
        auxiliary channel other than ``tension``, which the controller does not measure).
    """
    if not isinstance(effects, list):
        raise ConfigError(prefix, f"must be a list of effects, got {type(effects).__name__}")
    out = []
    for i, e in enumerate(effects):
        key = f"{prefix}[{i}]"
        if not isinstance(e, Mapping):
            raise ConfigError(key, "must be a mapping with effect, code, p")
        unknown = sorted(set(e) - ENTRY_KEYS)
        if unknown:
            raise ConfigError(f"{key}.{unknown[0]}", f"unknown key; allowed: {', '.join(sorted(ENTRY_KEYS))}")
        aux = e.get("aux")
        if aux not in (None, "tension"):
            raise ConfigError(f"{key}.aux", f"the controller has no channel {aux!r} (only the measured tension)")
        out.append({k: (list(v) if isinstance(v, (list, tuple)) else dict(v) if isinstance(v, Mapping) else v)
                    for k, v in e.items()})
    pack_effects(out, prefix)
    return tuple(out)


def pack_block(effects: Sequence[Mapping[str, Any]], alpha_s_rad: float, eta_s_rad_s: float, zeta_s: float,
               v_rest_rad_s: float, prefix: str = "controller.feedforward.effects") -> np.ndarray:
    """The config-array tail for ``effects`` (layout in the module docstring).

    :raises ConfigError: on a malformed effect entry.
    """
    codes, P, K, E, O, nk = pack_effects(list(effects), prefix)
    kmax = K.shape[1]
    stride = E_P + N_P + 3 * kmax
    b = np.zeros(B_HEAD + len(effects) * stride)
    b[B_N], b[B_ALPHA], b[B_ETA], b[B_ZETA], b[B_V_REST], b[B_KMAX] = (
        len(effects), alpha_s_rad, eta_s_rad_s, zeta_s, v_rest_rad_s, kmax)
    for i, e in enumerate(effects):
        o = B_HEAD + i * stride
        b[o + E_CODE] = codes[i]
        b[o + E_AUX] = AUX_TENSION if e.get("aux") == "tension" else AUX_NONE
        b[o + E_NK] = nk[i]
        b[o + E_P:o + E_P + N_P] = P[i]
        k0 = o + E_P + N_P
        b[k0:k0 + kmax], b[k0 + kmax:k0 + 2 * kmax], b[k0 + 2 * kmax:k0 + 3 * kmax] = K[i], E[i], O[i]
    return b


@njit(cache=True)
def learned_effects_Nm(cfg: np.ndarray, off: int, st: np.ndarray, s: int, t_s: float, q_rad: float,
                       dq_rad_s: float, load_Nm: float, tension_N: float) -> float:
    """Sum of the learned effects [Nm] at a new IMU sample; updates the state from ``s``.

    Returns 0.0 (and touches nothing) when the block holds no effect.
    """
    n = int(cfg[off + B_N])
    if n == 0:
        return 0.0
    if st[s + F_INIT] == 0.0:
        st[s + F_DWELL] = 0.0               # smoothed speed
        st[s + F_DWELL + 1] = 0.0           # moving flag
        st[s + F_DWELL + 2] = 10.0          # dwell: assume a long rest before the start
        st[s + F_DWELL + 3] = 10.0          # rest
        st[s + F_DWELL + 4] = 0.0           # slide
        st[s + F_T_PREV] = t_s
        st[s + F_DQ_PREV] = dq_rad_s
        st[s + F_DDQ] = 0.0
        st[s + F_T0] = t_s
        st[s + F_INIT] = 1.0
    dt = t_s - st[s + F_T_PREV]
    if dt > 0.0:
        dwell_update(st[s + F_DWELL:s + F_DWELL + 5], dq_rad_s, dt, cfg[off + B_V_REST])
        a = min(1.0, dt / DDQ_TAU_S)
        st[s + F_DDQ] += a * ((dq_rad_s - st[s + F_DQ_PREV]) / dt - st[s + F_DDQ])
    st[s + F_T_PREV] = t_s
    st[s + F_DQ_PREV] = dq_rad_s
    sh = friction_shape(dq_rad_s, cfg[off + B_ALPHA], cfg[off + B_ETA], cfg[off + B_ZETA])
    rest = st[s + F_DWELL + 3]
    slide = st[s + F_DWELL + 4]
    kmax = int(cfg[off + B_KMAX])
    stride = E_P + N_P + 3 * kmax
    tot = 0.0
    for i in range(n):
        o = off + B_HEAD + i * stride
        k = int(cfg[o + E_NK])
        k0 = o + E_P + N_P
        aux = tension_N if int(cfg[o + E_AUX]) == AUX_TENSION else 0.0
        tot += effect_loss_Nm(int(cfg[o + E_CODE]), cfg[o + E_P:o + E_P + N_P], cfg[k0:k0 + k],
                              cfg[k0 + kmax:k0 + kmax + k], cfg[k0 + 2 * kmax:k0 + 2 * kmax + k], sh, dq_rad_s,
                              st[s + F_DDQ], q_rad, rest, slide, t_s - st[s + F_T0], load_Nm, aux)
    return tot
