"""The reduced model's torsional unit with friction as a state (paper eqs 14-21, eq 20 in
output-error form): stick holds the elastic state, breakaway happens where the friction
capacity is exceeded.

Every driving form of the closure (see :mod:`capstan.models.closure.dynamic.baseline`) reduces
to one scalar state ``x`` [rad] -- the sheath node of the torsional unit, or the output
angle on the testbed -- whose velocity ``v`` obeys the torque balance::

    c0 v + f + b_vis v = a(t) - kx x,          f = friction torque carried by the sheath [Nm]

The friction torque is a state of its own (elasto-plastic, generalised Dahl form with
exponent ``i > 0``, dimensionless)::

    df/dx = k_pre sgn(u) |u|^i,   u = 1 - sgn(v) f / F(v),
    F(v) = tau_fc [1 + (zeta_s - 1) exp(-(v / eta_s)^2)]

* stick: while ``|f|`` is below the capacity ``F`` the sheath holds the elastic state with
  the presliding stiffness ``k_pre 2^i`` right after a reversal [Nm/rad] (``v = 0`` whenever
  the demanded friction does not change; as ``k_pre -> inf`` this is the set-valued Coulomb
  stick of a rigid node);
* breakaway where the demanded friction exceeds the capacity: ``f`` saturates at
  ``+-F(v)``, the eq-21 Stribeck-Coulomb law (``zeta_c = 1``) with the sign of the motion
  in place of the tanh (the state carries the stick phase the tanh only approximates).
* the exponent shapes the stick-to-slip transition (the capacity mobilised progressively
  along the sheath, as the distributed model's slip zone spreads from the input).
  ``i = 1`` is Dahl's law: the stiffness falls in proportion to the capacity still unused,
  ``f`` reaches ``F`` only asymptotically (travel scale ``F / k_pre``). ``i = 1/2`` is an
  Iwan element with slip thresholds spread uniformly over ``[0, 2F]``: ``f`` is a parabola
  in the travel. ``i < 1`` saturates after the finite travel
  ``x_sat = |u0|^(1-i) F / ((1-i) k_pre)`` (``2^(1-i) F / ((1-i) k_pre)`` after a full
  reversal, ``u0 = 2``); ``i -> 0`` is the elasto-plastic (Jenkins) element, stiffness
  ``k_pre`` until ``f = F``. ``i > 1``: a stiff start that softens quickly and a long tail
  (thresholds crowded at the low end, a few far above: ``i = 2`` approaches ``F``
  hyperbolically, ``u = u0 / (1 + u0 k_pre x / F)``).

Time stepping over each sample interval ``dt``: the new velocity ``v`` is implicit
(backward Euler), ``(c0 + kx dt + b_vis) v + f_new(v) = a_i - kx x_{i-1}``, solved by a
bracketed Newton iteration started at the previous velocity (a Stribeck dip keeps the branch
the motion is on). The friction over the step at that constant velocity:

* ``i = 1``: backward Euler, ``f_new = (f + k_pre dt v) / (1 + k_pre dt |v| / F(v))``;
* ``i != 1``: the exact solution at constant ``v`` (travel ``|v| dt``),
  ``|u_new|^(1-i) = max(0, |u|^(1-i) - (1-i) k_pre |v| dt / F)``, sign of ``u`` kept
  (:func:`dahl_u_update`; it tends to Dahl's exact ``u exp(-k_pre |v| dt / F)`` as
  ``i -> 1``, which backward Euler approaches as ``dt -> 0``: ``i = 1`` keeps backward Euler
  so the unit's earlier results are unchanged bit for bit).

``c0 + kx dt + b_vis > 0`` is required (a stiffness or a damping in every form).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Newton iterations per slipping sample (the bracket halves at worst)
MAX_ITER = 60


#: anchors of a path that is not there (never read: its h is 0)
_NO_ANCHOR = np.empty(0)


@njit(cache=True)
def capacity_Nm(v_rad_s: float, tau_fc_Nm: float, zeta_s: float, eta_s_rad_s: float) -> float:
    """Friction capacity at speed ``v``: ``tau_fc [1 + (zeta_s - 1) exp(-(v/eta_s)^2)]`` [Nm] (eq 21, zeta_c = 1)."""
    x = v_rad_s / eta_s_rad_s
    return tau_fc_Nm * (1.0 + (zeta_s - 1.0) * math.exp(-x * x))


@njit(cache=True)
def dahl_u_update(u: float, travel_rad: float, k_pre_Nm_rad: float, F_Nm: float, dahl_exp: float) -> float:
    """Unused capacity fraction ``u = 1 - sgn(v) f / F`` after the travel ``|v| dt`` [rad] in
    one direction: the exact solution of ``du/dx = -(k_pre / F) sgn(u) |u|^i``,
    ``i = dahl_exp``. ``i < 1``: ``|u|^(1-i)`` falls linearly and reaches 0 after a finite
    travel; ``i = 1``: ``u exp(-k_pre x / F)``; ``i > 1``: ``|u|^(1-i)`` grows linearly (a
    hyperbolic approach for ``i = 2``). The sign of ``u`` is kept (``u < 0``: ``f`` beyond a
    capacity that fell, relaxing back to it). Needs ``F_Nm > 0``, ``dahl_exp > 0``."""
    if u == 0.0 or travel_rad <= 0.0:
        return u
    a = k_pre_Nm_rad * travel_rad / F_Nm
    e = 1.0 - dahl_exp
    if abs(e) < 1e-9:
        return u * math.exp(-a)
    w = abs(u) ** e - e * a
    if w <= 0.0:
        return 0.0
    r = w ** (1.0 / e)
    return r if u > 0.0 else -r


@njit(cache=True)
def friction_update(f_Nm: float, v_rad_s: float, dt_s: float, k_pre_Nm_rad: float, tau_fc_Nm: float,
                    zeta_s: float, eta_s_rad_s: float, dahl_exp: float = 1.0) -> float:
    """Friction state after one step at velocity ``v`` [Nm] (module docstring: backward Euler
    for ``dahl_exp = 1``, the exact constant-velocity solution otherwise).

    ``df = k_pre sgn(u) |u|^i dx``: elastic (stick) with stiffness ``k_pre`` while ``|f|``
    is well below the capacity ``F``, saturating at ``+-F`` in slip.
    """
    F = capacity_Nm(v_rad_s, tau_fc_Nm, zeta_s, eta_s_rad_s)
    if not F > 0.0:
        return 0.0
    if dahl_exp == 1.0:
        return (f_Nm + k_pre_Nm_rad * dt_s * v_rad_s) / (1.0 + k_pre_Nm_rad * dt_s * abs(v_rad_s) / F)
    if v_rad_s == 0.0:
        return f_Nm
    sg = 1.0 if v_rad_s > 0.0 else -1.0
    u = dahl_u_update(1.0 - sg * f_Nm / F, abs(v_rad_s) * dt_s, k_pre_Nm_rad, F, dahl_exp)
    return sg * F * (1.0 - u)


@njit(cache=True)
def step_velocity(rhs_Nm: float, c_Nms_rad: float, v_prev_rad_s: float, f_Nm: float, dt_s: float,
                  k_pre_Nm_rad: float, tau_fc_Nm: float, zeta_s: float, eta_s_rad_s: float,
                  b_vis_Nms_rad: float, c2_Nms2_rad2: float = 0.0, dahl_exp: float = 1.0,
                  h1_Nm_rad3: float = 0.0, e1_rad: float = 0.0, h2_Nm_rad3: float = 0.0,
                  e2_rad: float = 0.0) -> float:
    """Velocity of one backward-Euler step [rad/s]: the root of
    ``c v + f_new(v) + b_vis v + c2 v |v| + P(v) = rhs`` (``f_new`` by :func:`friction_update`
    from ``f`` with exponent ``dahl_exp``; ``c2 >= 0`` a drag growing with speed).

    ``P(v) = sum_j h_j [e_j^3 - (e_j - dt v)^3]`` is the change over the step of the cubic
    part of hardening springs (:mod:`capstan.models.transmission.hardening`): spring ``j``
    pulls the node with ``K_j e (1 + c e^2)``, ``e`` its stretch towards its anchor, ``e_j``
    at the step's start, ``h_j = c K_j >= 0`` [Nm/rad^3]; ``rhs`` includes the cubic force at
    the step's start. ``P`` is increasing and ``P(0) = 0``, so the root is unique.

    Bracketed by ``(rhs -/+ M) / (c + b_vis)`` with ``M = max(|f|, zeta_s tau_fc)`` (with
    hardening springs, widened to contain 0: ``P`` has the sign of ``v``); Newton
    steps (derivative without the Stribeck slope) safeguarded by bisection, started at the
    previous velocity. Returns NaN if ``c + b_vis <= 0``.
    """
    ct = c_Nms_rad + b_vis_Nms_rad
    if not ct > 0.0:
        return math.nan
    M = max(abs(f_Nm), zeta_s * tau_fc_Nm)
    lo = (rhs_Nm - M) / ct
    hi = (rhs_Nm + M) / ct
    hard = h1_Nm_rad3 != 0.0 or h2_Nm_rad3 != 0.0
    if hard:
        lo = min(lo, 0.0)
        hi = max(hi, 0.0)
    if hi - lo <= 0.0:
        return lo
    v = min(max(v_prev_rad_s, lo), hi)
    scale = abs(rhs_Nm) + M + 1e-12
    kd = k_pre_Nm_rad * dt_s
    for _ in range(MAX_ITER):
        F = capacity_Nm(v, tau_fc_Nm, zeta_s, eta_s_rad_s)
        sg = 1.0 if v >= 0.0 else -1.0
        if dahl_exp == 1.0:
            den = 1.0 + kd * abs(v) / F if F > 0.0 else math.inf
            fn = (f_Nm + kd * v) / den if F > 0.0 else 0.0
            dfn = (kd * den - (f_Nm + kd * v) * kd * sg / F) / (den * den) if F > 0.0 else 0.0
        elif F > 0.0:
            # exact constant-velocity update; dfn/dv = kd sgn(u) |u_new|^i (Stribeck slope left out)
            u_new = dahl_u_update(1.0 - sg * f_Nm / F, abs(v) * dt_s, k_pre_Nm_rad, F, dahl_exp)
            fn = sg * F * (1.0 - u_new) if v != 0.0 else f_Nm
            dfn = kd * abs(u_new) ** dahl_exp * (1.0 if u_new >= 0.0 else -1.0)
        else:
            fn, dfn = 0.0, 0.0
        g = ct * v + c2_Nms2_rad2 * v * abs(v) + fn - rhs_Nm
        dg = ct + 2.0 * c2_Nms2_rad2 * abs(v) + dfn
        if hard:
            s1 = e1_rad - dt_s * v
            s2 = e2_rad - dt_s * v
            g += h1_Nm_rad3 * (e1_rad ** 3 - s1 ** 3) + h2_Nm_rad3 * (e2_rad ** 3 - s2 ** 3)
            dg += 3.0 * dt_s * (h1_Nm_rad3 * s1 * s1 + h2_Nm_rad3 * s2 * s2)
        if abs(g) <= 1e-10 * scale:
            return v
        if g < 0.0:
            lo = v
        else:
            hi = v
        v_new = v - g / dg if dg > 0.0 else 0.5 * (lo + hi)
        if not (lo < v_new < hi):
            v_new = 0.5 * (lo + hi)
        if hi - lo <= 1e-15 * (1.0 + abs(v)):
            return v_new
        v = v_new
    return v


@njit(cache=True, nogil=True)
def simulate_unit(t_s: np.ndarray, a_Nm: np.ndarray, starts: np.ndarray, x0_rad: np.ndarray, c0_Nms_rad: np.ndarray,
                  kx_Nm_rad: np.ndarray, k_pre_Nm_rad: float, tau_fc_Nm: float, zeta_s: float, eta_s_rad_s: float,
                  b_vis_Nms_rad: float, out_x_rad: np.ndarray, out_v_rad_s: np.ndarray, out_f_Nm: np.ndarray,
                  cap_scale: np.ndarray, c2_Nms2_rad2: float = 0.0, dahl_exp: float = 1.0) -> int:
    """Integrate the unit through concatenated runs (allocation-free).

    :param t_s: sample times [s] (increasing inside each run).
    :param a_Nm: driving torque ``a(t)`` per sample [Nm].
    :param starts: first index of each run, then the total length (``len(runs) + 1``).
    :param x0_rad: state at the first sample of each run [rad] (at rest there, no friction).
    :param c0_Nms_rad: damping ``c0`` of each run [Nm s/rad].
    :param kx_Nm_rad: stiffness ``kx`` of each run [Nm/rad].
    :param cap_scale: per-sample multiplier of the capacity ``tau_fc`` (effects acting on the
        friction: dwell, position, time, load), > 0; an empty array means 1 everywhere.
    :param c2_Nms2_rad2: drag ``c2 v |v|`` at speed [Nm s^2/rad^2].
    :param dahl_exp: exponent ``i > 0`` of the friction law (1: Dahl, backward Euler, as before).
    :returns: the number of samples integrated (``len(t_s)`` unless a step failed: NaN
        velocity, non-increasing time).
    """
    return simulate_paths(t_s, a_Nm, starts, x0_rad, c0_Nms_rad, kx_Nm_rad, k_pre_Nm_rad, tau_fc_Nm, zeta_s,
                          eta_s_rad_s, b_vis_Nms_rad, out_x_rad, out_v_rad_s, out_f_Nm, cap_scale, c2_Nms2_rad2,
                          dahl_exp, 0.0, _NO_ANCHOR, 0.0, _NO_ANCHOR)


@njit(cache=True, nogil=True)
def simulate_paths(t_s: np.ndarray, a_Nm: np.ndarray, starts: np.ndarray, x0_rad: np.ndarray, c0_Nms_rad: np.ndarray,
                   kx_Nm_rad: np.ndarray, k_pre_Nm_rad: float, tau_fc_Nm: float, zeta_s: float, eta_s_rad_s: float,
                   b_vis_Nms_rad: float, out_x_rad: np.ndarray, out_v_rad_s: np.ndarray, out_f_Nm: np.ndarray,
                   cap_scale: np.ndarray, c2_Nms2_rad2: float, dahl_exp: float, h1_Nm_rad3: float,
                   anchor1_rad: np.ndarray, h2_Nm_rad3: float, anchor2_rad: np.ndarray) -> int:
    """:func:`simulate_unit` with the cubic parts ``h_j (A_j - x)^3`` of up to two hardening elastic
    paths (:mod:`capstan.models.transmission.hardening`; ``h_j = c_node K_j >= 0`` [Nm/rad^3],
    anchors ``A_j`` per sample [rad]). A path with ``h_j = 0`` is not read (its anchors may be
    empty), and with both 0 every step does exactly the arithmetic of the linear unit.
    """
    hard = h1_Nm_rad3 != 0.0 or h2_Nm_rad3 != 0.0
    has_scale = cap_scale.shape[0] == t_s.shape[0]
    for k in range(starts.shape[0] - 1):
        a0 = starts[k]
        b0 = starts[k + 1]
        if b0 <= a0:
            continue
        x = x0_rad[k]
        c0 = c0_Nms_rad[k]
        kx = kx_Nm_rad[k]
        v = 0.0
        f = 0.0
        out_x_rad[a0] = x
        out_v_rad_s[a0] = 0.0
        out_f_Nm[a0] = 0.0
        for i in range(a0 + 1, b0):
            dt = t_s[i] - t_s[i - 1]
            if not dt > 0.0:
                return i
            c = c0 + kx * dt
            tfc = tau_fc_Nm * cap_scale[i] if has_scale else tau_fc_Nm
            rhs = a_Nm[i] - kx * x
            e1 = 0.0
            e2 = 0.0
            if hard:
                if h1_Nm_rad3 != 0.0:
                    e1 = anchor1_rad[i] - x
                if h2_Nm_rad3 != 0.0:
                    e2 = anchor2_rad[i] - x
                rhs = rhs + h1_Nm_rad3 * e1 * e1 * e1 + h2_Nm_rad3 * e2 * e2 * e2
            v = step_velocity(rhs, c, v, f, dt, k_pre_Nm_rad, tfc, zeta_s, eta_s_rad_s,
                              b_vis_Nms_rad, c2_Nms2_rad2, dahl_exp, h1_Nm_rad3, e1, h2_Nm_rad3, e2)
            if not math.isfinite(v):
                return i
            f = friction_update(f, v, dt, k_pre_Nm_rad, tfc, zeta_s, eta_s_rad_s, dahl_exp)
            x = x + dt * v
            out_x_rad[i] = x
            out_v_rad_s[i] = v
            out_f_Nm[i] = f
    return t_s.shape[0]
