"""Stiff integrator for the distributed tendon-sheath model.

Method: Alexander's two-stage, second-order, L-stable, stiffly accurate SDIRK
(gamma = 1 - 1/sqrt(2)) on ``M dy/dt = F(y)`` (``M`` diagonal), with full Newton
iterations on an analytic Jacobian. The Newton matrix ``M - h*gamma*J`` is a cyclic
tridiagonal on the ring ``q_in - upper chain - q_out - lower chain`` once the pulley
velocity states are eliminated, so each linear solve is O(N) (Thomas algorithm on the
chain with ``q_in`` as the border unknown, one Schur-complement scalar).

Error estimate (adaptive mode): ``e = y_{n+1} - y_hat`` with the embedded first-order
solution ``y_hat = y_n + h K_1``, i.e. ``e = h gamma (K_2 - K_1)``, filtered through
``(M - h gamma J)^-1 M`` (Shampine's filter, removes the spurious stiff part), RMS
norm with weights ``atol_i + rtol |y_i|``.

Newton: stops when the contraction-corrected increment (Hairer & Wanner IV.8) is below
:func:`newton_tol` in that weighted norm: ``max(10 eps / rtol, min(0.03, sqrt(rtol)))``,
the rule of scipy's Radau (1e-3 at the default rtol 1e-6, 1e-2 at rtol 1e-4: a small
fraction of the local error tolerance, which is 1 in this norm). The error filter reuses
the factors of the last Newton solve (:func:`_sweep`). Small helpers that take arrays are
inlined: a call that passes arrays costs Numba reference counting on every call.
Predictor: a step of the same size as the last one starts from the last step's stage
increments (this carries the response to the input jump of a held input, which a
derivative extrapolation cannot); other steps extrapolate with the last stage derivative.

Fixed mode: one step per interval; an interval is split (step quartered) only when
Newton does not converge, and the step grows back afterwards. The offline adaptive run
across sample times is :mod:`models.distributed_dense`.

Every function returns a status code instead of raising (Numba); ``models.distributed``
turns codes into exceptions.
"""

from __future__ import annotations

import math

from numba import njit

from models.distributed_rhs import (BP_B_IN, BP_B_LINK, BP_B_M, BP_B_OUT, BP_CC,
                                    BP_IN_MODE, BP_J_M, BP_J_OUT, BP_K_OUT, BP_K_SEG,
                                    BP_OUT_MODE, BP_R_IN, BP_R_OUT, OUT_LINK,
                                    OUT_TESTBED_MASSLESS, eval_system, mass_diag,
                                    min_tension, segment_forces)

GAMMA = 1.0 - 1.0 / math.sqrt(2.0)

OK = 0
ERR_SLACK = 1
ERR_NEWTON = 2
ERR_NONFINITE = 3
ERR_PARAM = 4       # a per-node parameter out of range (checked by the model's step kernel)

# rows of the work array
(W_Y0, W_Z1, W_Z2, W_PSI, W_K1, W_F, W_M, W_ATOL, W_DEL, W_R, W_E, W_CP, W_ZZ, W_WW,
 W_FS, W_KT, W_JLO, W_JDI, W_JUP, W_KP, W_P1, W_P2, W_HP, W_YI, W_INV) = range(25)
N_WORK = 25
# W_KP: last stage derivative; W_P1, W_P2: stage increments Z1 - Y0 and Z2 - Z1 of the last
# accepted step; W_HP[0]: that step's size [s] (0 = none). Zeroed by the model's reset.
# W_YI: interpolated state (dense output). W_CP, W_INV, W_WW: factors of M - hg J left by
# _solve for _sweep.

# stats slots
S_STEPS, S_RHS, S_REJECT, S_NEWTON_FAIL, S_H, S_ETA = range(6)
N_STATS = 6
# info slots for errors: time, segment index, tension
I_T, I_SEG, I_TENSION = range(3)

NEWTON_MAXIT = 12
_EPS = 2.220446049250313e-16
H_MIN_S = 1e-12


@njit(cache=True, inline="always")
def _second_order_in(bp) -> bool:
    return bp[BP_IN_MODE] != 0.0


@njit(cache=True, inline="always")
def _second_order_out(bp) -> bool:
    return int(bp[BP_OUT_MODE]) != OUT_TESTBED_MASSLESS


@njit(cache=True, inline="always")
def _damp_out(bp) -> float:
    if int(bp[BP_OUT_MODE]) == OUT_LINK:
        return bp[BP_B_LINK]
    return bp[BP_B_OUT]


# _solve, _sweep and _wrms (the divisions of every Newton iteration) use Numba's numpy
# error model: no zero-divisor check per division; a zero pivot or weight gives inf/NaN,
# which the Newton iteration treats as divergence (step size reduced, then ERR_NEWTON).
@njit(cache=True, error_model="numpy")
def _solve(n, hg, R, work, bp, D):
    """Solve ``(M - hg J) D = -R`` (cyclic tridiagonal + eliminated velocities).

    Thomas algorithm on the chain rows ``1..m-1`` with two right-hand sides (``-R`` and
    the border column of ``q_in``), then one Schur-complement scalar for ``q_in``; the
    matrix entries are formed on the fly from the ring Jacobian. The factors (reciprocal
    pivots in W_INV with the Schur pivot in ``work[W_INV, 0]``, multipliers in W_CP, border
    solution in W_WW) stay in ``work`` for :func:`_sweep`. Elimination and first right-hand
    side run in one pass: the pivot recursion is latency-bound and the right-hand side
    rides along in its shadow.
    """
    m = 2 * n + 2
    jo = n + 1
    M = work[W_M]
    jl = work[W_JLO]
    jd = work[W_JDI]
    ju = work[W_JUP]
    cp = work[W_CP]
    inv_p = work[W_INV]
    z = work[W_ZZ]
    w = work[W_WW]
    di0 = M[0] - hg * jd[0]
    r0 = -R[0]
    if _second_order_in(bp):
        A = (bp[BP_J_M] + hg * bp[BP_B_M]) / hg
        di0 = A - hg * jd[0]
        r0 = -R[m] - A * R[0]
    dio = M[jo] - hg * jd[jo]
    ro = -R[jo]
    if _second_order_out(bp):
        A = (bp[BP_J_OUT] + hg * _damp_out(bp)) / hg
        dio = A - hg * jd[jo]
        ro = -R[m + 1] - A * R[jo]
    # forward sweep; border column entries: row 1 (lower neighbour q_in), row m-1 (upper)
    zp = 0.0
    wp = 0.0
    cpp = 0.0
    for j in range(1, m):
        lo = -hg * jl[j]
        if j == jo:
            d = dio
            r = ro
        else:
            d = M[j] - hg * jd[j]
            r = -R[j]
        inv = 1.0 / (d - lo * cpp)
        zp = (r - lo * zp) * inv
        if j == 1:
            wp = lo * inv
        elif j == m - 1:
            wp = (-hg * ju[j] - lo * wp) * inv
        else:
            wp = -lo * wp * inv
        cpp = -hg * ju[j] * inv if j < m - 1 else 0.0
        inv_p[j] = inv
        z[j] = zp
        w[j] = wp
        cp[j] = cpp
    for j in range(m - 2, 0, -1):
        z[j] -= cp[j] * z[j + 1]
        w[j] -= cp[j] * w[j + 1]
    up0 = -hg * ju[0]
    lo0 = -hg * jl[0]
    den = di0 - up0 * w[1] - lo0 * w[m - 1]
    inv_p[0] = den
    x0 = (r0 - up0 * z[1] - lo0 * z[m - 1]) / den
    _finish(n, hg, R, bp, z, w, x0, D)


@njit(cache=True, error_model="numpy", inline="always")
def _finish(n, hg, R, bp, z, w, x0, D):
    """Back-substitute the border unknown ``x0`` and recover eliminated velocities."""
    m = 2 * n + 2
    D[0] = x0
    for j in range(1, m):
        D[j] = z[j] - w[j] * x0
    D[m] = 0.0
    D[m + 1] = 0.0
    if _second_order_in(bp):
        D[m] = (D[0] + R[0]) / hg
    if _second_order_out(bp):
        D[m + 1] = (D[n + 1] + R[n + 1]) / hg


@njit(cache=True, error_model="numpy")
def _sweep(n, hg, R, work, bp, D):
    """Solve ``(M - hg J) D = -R`` with the factors left in ``work`` by the last
    :func:`_solve` (same ``hg`` and Jacobian); same operations on the right-hand side."""
    m = 2 * n + 2
    jo = n + 1
    jl = work[W_JLO]
    ju = work[W_JUP]
    cp = work[W_CP]
    inv_p = work[W_INV]
    z = work[W_ZZ]
    w = work[W_WW]
    r0 = -R[0]
    if _second_order_in(bp):
        r0 = -R[m] - (bp[BP_J_M] + hg * bp[BP_B_M]) / hg * R[0]
    ro = -R[jo]
    if _second_order_out(bp):
        ro = -R[m + 1] - (bp[BP_J_OUT] + hg * _damp_out(bp)) / hg * R[jo]
    zp = 0.0
    for j in range(1, m):
        lo = -hg * jl[j]
        r = ro if j == jo else -R[j]
        zp = (r - lo * zp) * inv_p[j]
        z[j] = zp
    for j in range(m - 2, 0, -1):
        z[j] -= cp[j] * z[j + 1]
    up0 = -hg * ju[0]
    lo0 = -hg * jl[0]
    x0 = (r0 - up0 * z[1] - lo0 * z[m - 1]) / inv_p[0]
    _finish(n, hg, R, bp, z, w, x0, D)


@njit(cache=True, error_model="numpy")
def _wrms(v, y, atolv, rtol, n_eff) -> float:
    s = 0.0
    for i in range(v.shape[0]):
        wi = atolv[i] + rtol * abs(y[i])
        r = v[i] / wi
        s += r * r
    return math.sqrt(s / n_eff)


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
    n_eff = float(m + (1 if _second_order_in(bp) else 0) + (1 if _second_order_out(bp) else 0))
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
        _solve(n, hg, R, work, bp, D)
        for i in range(m + 2):
            Z[i] += D[i]
        nrm = _wrms(D, Z, atolv, rtol, n_eff)
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
    _sweep(n, hg, R, work, bp, D)
    n_eff = float(m + (1 if _second_order_in(bp) else 0) + (1 if _second_order_out(bp) else 0))
    return _wrms(D, Z2, work[W_ATOL], rtol, n_eff)


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

