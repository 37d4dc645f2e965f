"""Stiff integrator for the distributed tendon-sheath model.

Method: Alexander's two-stage, second-order, L-stable, stiffly accurate SDIRK
(gamma = 1 - 1/sqrt(2)) on ``M dy/dt = F(y)`` (``M`` diagonal), with full Newton
iterations on an analytic Jacobian. The Newton matrix ``M - h*gamma*J`` is a cyclic
tridiagonal once the pulley velocity states are eliminated, so each linear solve is O(N)
(:mod:`capstan.models.distributed.linsolve`).

Error estimate (adaptive mode): ``e = y_{n+1} - y_hat`` with the embedded first-order
solution ``y_hat = y_n + h K_1``, i.e. ``e = h gamma (K_2 - K_1)``, filtered through
``(M - h gamma J)^-1 M`` (Shampine's filter, removes the spurious stiff part), RMS
norm with weights ``atol_i + rtol |y_i|``.

Newton: stops when the contraction-corrected increment (Hairer & Wanner IV.8) is below
:func:`newton_tol` in that weighted norm: ``max(10 eps / rtol, min(0.03, sqrt(rtol)))``,
the rule of scipy's Radau (1e-3 at the default rtol 1e-6, 1e-2 at rtol 1e-4: a small
fraction of the local error tolerance, which is 1 in this norm). The error filter reuses
the factors of the last Newton solve (:func:`capstan.models.distributed.linsolve.sweep`).
Predictor: a step of the same size as the last one starts from the last step's stage
increments (this carries the response to the input jump of a held input, which a
derivative extrapolation cannot); other steps extrapolate with the last stage derivative.

Fixed mode: one step per interval; an interval is split (step quartered) only when
Newton does not converge, and the step grows back afterwards. The offline adaptive run
across sample times is :mod:`capstan.models.distributed.dense`.

Every function returns a status code instead of raising (Numba); ``models.distributed``
turns codes into exceptions.
"""

from __future__ import annotations

import math

from numba import njit

from capstan.models.distributed.linsolve import live_states, solve, sweep, wrms
from capstan.models.distributed.rhs import (BP_B_IN, BP_B_OUT, BP_IN_MODE, BP_K_OUT, BP_OUT_MODE,
                                    BP_R_IN, BP_R_OUT, OUT_TESTBED_MASSLESS, eval_system,
                                    mass_diag, min_tension, segment_forces)
# the buffer layout, re-exported: callers use ``di.W_*``, ``di.S_*``, ``di.ERR_*``
from capstan.models.distributed.work import (ERR_NEWTON, ERR_NONFINITE, ERR_PARAM, ERR_SLACK,  # noqa: F401
                                     I_SEG, I_T, I_TENSION, N_STATS, N_WORK, OK, S_ETA, S_H,
                                     S_NEWTON_FAIL, S_REJECT, S_RHS, S_STEPS, W_ATOL, W_CP,
                                     W_DEL, W_E, W_F, W_FS, W_HP, W_INV, W_JDI, W_JLO, W_JUP,
                                     W_K1, W_KP, W_KT, W_M, W_P1, W_P2, W_PSI, W_R, W_WW, W_Y0,
                                     W_YI, W_Z1, W_Z2, W_ZZ)

GAMMA = 1.0 - 1.0 / math.sqrt(2.0)

NEWTON_MAXIT = 12
_EPS = 2.220446049250313e-16
H_MIN_S = 1e-12


@njit(cache=True)
def newton_tol(rtol: float) -> float:
    """Newton stopping tolerance in the weighted RMS norm for relative tolerance ``rtol``."""
    return max(10.0 * _EPS / rtol, min(0.03, math.sqrt(rtol)))


@njit(cache=True)
def _newton(n, Z, psi, hg, u, text, d0, c_node, b_node, bp, work, rtol, stats) -> bool:
    """Solve ``M (Z - psi) - hg F(Z) = 0`` in place. Returns True on convergence."""
    m = 2 * n + 2
    M = work[W_M]
    F = work[W_F]
    R = work[W_R]
    D = work[W_DEL]
    atolv = work[W_ATOL]
    f_seg = work[W_FS]
    kt_seg = work[W_KT]
    j_lo = work[W_JLO]
    j_di = work[W_JDI]
    j_up = work[W_JUP]
    n_eff = live_states(n, bp)
    # convergence test of Hairer & Wanner (IV.8): stop when eta * |dZ| <= tol with the
    # contraction estimate eta = theta / (1 - theta), carried over between solves
    eta = max(stats[S_ETA], 1e-16) ** 0.8 if stats[S_ETA] > 0.0 else 1.0
    tol = newton_tol(rtol)
    prev = 1e300
    for it in range(NEWTON_MAXIT):
        eval_system(Z, u, text, n, d0, c_node, b_node, bp, f_seg, kt_seg, F, j_lo, j_di, j_up)
        stats[S_RHS] += 1.0
        for i in range(m + 2):
            R[i] = M[i] * (Z[i] - psi[i]) - hg * F[i]
        solve(n, hg, R, work, bp, D)
        for i in range(m + 2):
            Z[i] += D[i]
        nrm = wrms(D, Z, atolv, rtol, n_eff)
        if not math.isfinite(nrm):
            return False
        if it > 0:
            theta = nrm / prev
            if theta >= 0.99:
                if it >= 3 and nrm > 2.0 * prev:
                    return False
                eta = 1e3
            else:
                eta = theta / (1.0 - theta)
        if eta * nrm <= tol or nrm <= 1e-3 * tol:
            stats[S_ETA] = eta
            return True
        prev = nrm
    return False


@njit(cache=True)
def try_step(n, y, h, u1, e1, u2, e2, d0, c_node, b_node, bp, work, rtol, adaptive,
             stats) -> float:
    """One SDIRK2 step of size ``h`` from ``y`` into work[W_Z2] (stages in W_Z1, W_Z2).

    :param u1, e1: input and external torque at the first stage time ``t + gamma h``.
    :param u2, e2: the same at ``t + h``.
    :returns: the error norm (0 if not ``adaptive``; inf on Newton failure).
    """
    m = 2 * n + 2
    g = GAMMA
    hg = h * g
    Y0 = work[W_Y0]
    Z1 = work[W_Z1]
    Z2 = work[W_Z2]
    psi = work[W_PSI]
    K1 = work[W_K1]
    Kp = work[W_KP]
    P1 = work[W_P1]
    P2 = work[W_P2]
    # predictor: a step of the same size as the last one repeats its stage increments
    # (this also carries the response to an input jump of a held input, which the stage
    # derivative cannot); otherwise extrapolate with the last stage derivative
    repeat = abs(work[W_HP, 0] - h) <= 1e-6 * h
    for i in range(m + 2):
        Y0[i] = y[i]
    # stage 1
    for i in range(m + 2):
        psi[i] = Y0[i]
        Z1[i] = Y0[i] + (P1[i] if repeat else hg * Kp[i])
    if not _newton(n, Z1, psi, hg, u1, e1, d0, c_node, b_node, bp, work, rtol, stats):
        return math.inf
    for i in range(m + 2):
        K1[i] = (Z1[i] - Y0[i]) / hg
    # stage 2
    for i in range(m + 2):
        psi[i] = Y0[i] + h * (1.0 - g) * K1[i]
        Z2[i] = (Z1[i] + P2[i]) if repeat else (Y0[i] + h * K1[i])
    if not _newton(n, Z2, psi, hg, u2, e2, d0, c_node, b_node, bp, work, rtol, stats):
        return math.inf
    if not adaptive:
        return 0.0
    E = work[W_E]
    D = work[W_DEL]
    M = work[W_M]
    for i in range(m + 2):
        E[i] = (Z2[i] - psi[i]) - (Z1[i] - Y0[i])
    # filter: D = (M - hg J)^-1 M E with the factors of the last Newton iteration
    R = work[W_R]
    for i in range(m + 2):
        R[i] = -M[i] * E[i]
    sweep(n, hg, R, work, bp, D)
    return wrms(D, Z2, work[W_ATOL], rtol, live_states(n, bp))


@njit(cache=True)
def setup(n, b_node, bp, atol, work):
    """Mass diagonal and absolute-tolerance vector into ``work`` (once per call)."""
    m = 2 * n + 2
    mass_diag(n, b_node, bp, work[W_M])
    atolv = work[W_ATOL]
    for j in range(m + 2):
        atolv[j] = atol
    atolv[m] = atol * 1e3
    atolv[m + 1] = atol * 1e3


@njit(cache=True)
def accept(n, h, t_new, y, d0, bp, work, stats, info) -> int:
    """Commit the step in ``work`` (size ``h``, ending at ``t_new``) into ``y``; check slack.

    :returns: OK, ERR_SLACK or ERR_NONFINITE (``info`` filled).
    """
    m = 2 * n + 2
    hg = h * GAMMA
    Y0 = work[W_Y0]
    Z1 = work[W_Z1]
    Z2 = work[W_Z2]
    psi = work[W_PSI]
    Kp = work[W_KP]
    P1 = work[W_P1]
    P2 = work[W_P2]
    for i in range(m + 2):
        Kp[i] = (Z2[i] - psi[i]) / hg
        P1[i] = Z1[i] - Y0[i]
        P2[i] = Z2[i] - Z1[i]
        y[i] = Z2[i]
    work[W_HP, 0] = h
    stats[S_STEPS] += 1.0
    fseg = work[W_FS][:m]
    segment_forces(y, n, d0, bp, fseg)
    jm, fm = min_tension(fseg)
    if not math.isfinite(fm):
        info[I_T] = t_new
        return ERR_NONFINITE
    if fm <= 0.0:
        info[I_T] = t_new
        info[I_SEG] = jm
        info[I_TENSION] = fm
        return ERR_SLACK
    return OK


@njit(cache=True)
def step_factor(err: float) -> float:
    """Step-size factor after an error norm ``err`` (first-order estimate, safety 0.9)."""
    if err <= 1e-8:
        return 4.0
    return min(4.0, max(0.2, 0.9 / math.sqrt(err)))


@njit(cache=True)
def advance(y, t0, t1, u_a, u_b, ta, tb, n, d0, c_node, b_node, bp, rtol, atol,
            adaptive, work, stats, info) -> int:
    """Advance ``y`` in place from ``t0`` to ``t1``.

    :param u_a, u_b: input torque at t0 and t1 (linear in between; equal for a hold).
    :param ta, tb: external torque at t0 and t1.
    :param stats: (N_STATS,) counters; ``stats[S_H]`` carries the proposed step size.
    :param info: (3,) filled on failure: time [s], segment index, tension [N].
    :returns: status code (OK, ERR_SLACK, ERR_NEWTON, ERR_NONFINITE).
    """
    setup(n, b_node, bp, atol, work)
    span = t1 - t0
    t = t0
    h = span if not adaptive else min(stats[S_H], span) if stats[S_H] > 0 else span * 0.1
    h_prop = h
    while t < t1:
        remaining = t1 - t
        if h >= remaining * (1.0 - 1e-9):
            h = remaining
        s1 = (t + GAMMA * h - t0) / span
        s2 = (t + h - t0) / span
        err = try_step(n, y, h, u_a + (u_b - u_a) * s1, ta + (tb - ta) * s1,
                       u_a + (u_b - u_a) * s2, ta + (tb - ta) * s2, d0, c_node, b_node, bp,
                       work, rtol, adaptive, stats)
        if not math.isfinite(err):
            stats[S_NEWTON_FAIL] += 1.0
            h *= 0.25
            if h < H_MIN_S:
                info[I_T] = t
                return ERR_NEWTON
            continue
        if adaptive and err > 1.0:
            stats[S_REJECT] += 1.0
            h *= max(0.2, 0.9 / math.sqrt(err))
            if h < H_MIN_S:
                info[I_T] = t
                return ERR_NEWTON
            continue
        t = t + h if h < remaining else t1
        st = accept(n, h, t, y, d0, bp, work, stats, info)
        if st != OK:
            return st
        if adaptive:
            h_prop = h * step_factor(err)
            h = h_prop
        else:
            h = min(2.0 * h, span)
            h_prop = h
    stats[S_H] = h_prop
    return OK


@njit(cache=True)
def observe(y, u, n, d0, bp, f_seg, out):
    """Observations of state ``y`` into ``out``: q_in, dq_in, q_out, dq_out, tau_in, tau_out.

    ``dq`` of first-order pulleys is computed from their balance at input ``u``.
    """
    segment_forces(y, n, d0, bp, f_seg)
    observe_forces(y, u, n, bp, f_seg, out)


@njit(cache=True)
def observe_forces(y, u, n, bp, f_seg, out):
    """:func:`observe` with the segment tensions ``f_seg`` of ``y`` already computed."""
    m = 2 * n + 2
    tau_in = bp[BP_R_IN] * (f_seg[0] - f_seg[m - 1])
    tau_out = bp[BP_R_OUT] * (f_seg[n] - f_seg[n + 1])
    out[0] = y[0]
    if bp[BP_IN_MODE] == 0.0:
        out[1] = (u - tau_in) / bp[BP_B_IN]
    else:
        out[1] = y[m]
    out[2] = y[n + 1]
    if int(bp[BP_OUT_MODE]) == OUT_TESTBED_MASSLESS:
        out[3] = (tau_out - bp[BP_K_OUT] * y[n + 1]) / bp[BP_B_OUT]
    else:
        out[3] = y[m + 1]
    out[4] = tau_in
    out[5] = tau_out

