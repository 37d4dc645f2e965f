"""Friction feedforward of the reduced transmission model (paper eqs 19, 21, 25) and the
gravity model of the link.

Friction magnitude. With the paper's symmetric approximation (§4.4.1) the boundary
pretension is the mean of the four fixture tensions, ``T0 = mean(T_lc)``; with equal
ends the averaged pretension of eq (25) is linear in it, ``T0_eq = c(routing, mu) T0``, in
either reading of eq 25 (``feedforward.eq25_reading``, :class:`Eq25Reading`):
``c = 4 (1 - exp(-mu theta / 2)) / (mu theta)`` when it preserves the field's total friction
(default: the sliding friction of the distributed model, see docs/paper/report.md),
``c = 2 exp(-mu theta / 2)`` at the field minimum as printed. So is the nominal friction
torque of eq (19), ``tau_fc = mu theta T0_eq r_out``. The factor
``tau_fc / T0`` [Nm/N] is therefore computed once from the routing at config time
(:func:`friction_torque_per_N`) and the step scales it by the live pretension estimate.

Velocity shape (eq 21), evaluated with the IMU's ``dq_out`` (the paper's choice: the
output velocity gives a Coulomb-like, less hysteretic friction curve, Fig. 8f)::

    tau_fc_hat = tanh(alpha dq) [zeta_c + (zeta_s - zeta_c) exp(-(dq/eta_s)^2)] tau_fc + b_vis dq
"""

from __future__ import annotations

import numpy as np
from numba import njit

from capstan.controller.law.config import FeedforwardConfig
from capstan.models.transmission.pretension import Eq25Reading, pretension_field
from capstan.models.transmission.reduced import nominal_friction_torque_Nm, stribeck_friction_Nm


def friction_torque_per_N(ff: FeedforwardConfig, r_out_m: float) -> float:
    """Nominal friction torque per Newton of boundary pretension [Nm/N] for ``ff``'s routing,
    with ``T0_eq`` in ``ff.eq25_reading``.

    :raises ModelError: if the pretension field cannot be evaluated.
    """
    routing = ff.routing()
    t_ref = 100.0
    t0_eq = pretension_field(routing, ff.mu, t_ref, t_ref).T0_eq(Eq25Reading(ff.eq25_reading))
    return nominal_friction_torque_Nm(t0_eq, ff.mu, routing.theta_total_rad, r_out_m) / t_ref


@njit(cache=True)
def rest_gate(dq_rad_s: float, band_rad_s: float) -> float:
    """Factor [0, 1] on the feedforward: 0 for ``|dq| <= 0.8 band`` (rest: the rate is gyro
    noise), 1 from ``|dq| >= band`` on (the shape of eq 21 unchanged, so motion onset gets
    the full friction as soon as the rate leaves the noise), linear in between."""
    if band_rad_s <= 0.0:
        return 1.0
    a = abs(dq_rad_s)
    lo = 0.8 * band_rad_s
    if a <= lo:
        return 0.0
    if a >= band_rad_s:
        return 1.0
    return (a - lo) / (band_rad_s - lo)


@njit(cache=True)
def friction_feedforward_Nm(dq_out_rad_s: float, tau_fc_Nm: float, zeta_s: float, zeta_c: float,
                            eta_s_rad_s: float, alpha_s_rad: float, b_vis_Nms_rad: float) -> float:
    """Feedforward friction torque [Nm] (eq 21) at the output rate ``dq_out_rad_s``."""
    return stribeck_friction_Nm(dq_out_rad_s, tau_fc_Nm, zeta_s, zeta_c, eta_s_rad_s, alpha_s_rad,
                                b_vis_Nms_rad)


def friction_curve_Nm(dq_rad_s: np.ndarray, tau_fc_Nm: float, ff: FeedforwardConfig) -> np.ndarray:
    """Vectorised eq (21) for plots and tests [Nm]."""
    return np.array([friction_feedforward_Nm(float(v), tau_fc_Nm, ff.zeta_s, ff.zeta_c, ff.eta_s_rad_s,
                                             ff.alpha_s_rad, ff.b_vis_Nms_rad) for v in np.ravel(dq_rad_s)])


def rest_feedforward_series_Nm(dq_rad_s: np.ndarray, tau_fc_Nm: float, ff: FeedforwardConfig) -> np.ndarray:
    """The feedforward as the step evaluates it (eq 21 times the rest gate) on a series of
    gyro rates [Nm] (no learned effects, gain 1): for noise studies at rest."""
    out = np.zeros(np.size(dq_rad_s))
    prev_out = False
    for i, v in enumerate(np.ravel(dq_rad_s)):     # one IMU sample each, gate as in the step
        g = rest_gate(float(v), ff.dead_band_rad_s)
        out[i] = (g if prev_out else 0.0) * friction_feedforward_Nm(float(v), tau_fc_Nm, ff.zeta_s, ff.zeta_c,
                                                                   ff.eta_s_rad_s, ff.alpha_s_rad, ff.b_vis_Nms_rad)
        prev_out = g > 0.0
    return out
