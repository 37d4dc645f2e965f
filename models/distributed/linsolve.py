"""Linear algebra of the distributed integrator's Newton iteration (Numba).

The Newton matrix ``M - hg J`` of ``M dy/dt = F(y)`` is a cyclic tridiagonal on the ring
``q_in - upper chain - q_out - lower chain`` once the pulley velocity states are
eliminated: :func:`solve` factors it and solves in O(N) (Thomas algorithm on the chain
with ``q_in`` as the border unknown, one Schur-complement scalar), :func:`sweep` reuses
the factors for another right-hand side, :func:`wrms` is the weighted RMS norm of the
error and Newton tests. Small helpers that take arrays are inlined: a call that passes
arrays costs Numba reference counting on every call.
"""

from __future__ import annotations

import math

from numba import njit

from capstan.models.distributed.rhs import (BP_B_LINK, BP_B_M, BP_B_OUT, BP_IN_MODE, BP_J_M,
                                    BP_J_OUT, BP_OUT_MODE, OUT_LINK, OUT_TESTBED_MASSLESS)
from capstan.models.distributed.work import W_CP, W_INV, W_JDI, W_JLO, W_JUP, W_M, W_WW, W_ZZ


@njit(cache=True, inline="always")
def second_order_in(bp) -> bool:
    """True when the input pulley has a velocity state (MOTOR input mode)."""
    return bp[BP_IN_MODE] != 0.0


@njit(cache=True, inline="always")
def second_order_out(bp) -> bool:
    """True when the output pulley has a velocity state (inertia on the output side)."""
    return int(bp[BP_OUT_MODE]) != OUT_TESTBED_MASSLESS


@njit(cache=True, inline="always")
def live_states(n: int, bp) -> float:
    """Number of live state components (ring entries plus velocity states), the divisor of
    :func:`wrms` (unused velocity slots hold 0)."""
    return float(2 * n + 2 + (1 if second_order_in(bp) else 0) + (1 if second_order_out(bp) else 0))


@njit(cache=True, inline="always")
def _in_coef(hg: float, bp) -> float:
    """``(J_m + hg b_m) / hg``: the input velocity row eliminated into the q_in row."""
    return (bp[BP_J_M] + hg * bp[BP_B_M]) / hg


@njit(cache=True, inline="always")
def _out_coef(hg: float, bp) -> float:
    """``(J_out + hg b_out) / hg``: the output velocity row eliminated into the q_out row."""
    return (bp[BP_J_OUT] + hg * damp_out(bp)) / hg


@njit(cache=True, inline="always")
def damp_out(bp) -> float:
    """Viscous damping on the output pulley [Nm s/rad] (link or testbed)."""
    if int(bp[BP_OUT_MODE]) == OUT_LINK:
        return bp[BP_B_LINK]
    return bp[BP_B_OUT]


# solve, sweep and wrms (the divisions of every Newton iteration) use Numba's numpy
# error model: no zero-divisor check per division; a zero pivot or weight gives inf/NaN,
# which the Newton iteration treats as divergence (step size reduced, then ERR_NEWTON).
@njit(cache=True, error_model="numpy")
def solve(n, hg, R, work, bp, D):
    """Solve ``(M - hg J) D = -R`` (cyclic tridiagonal + eliminated velocities).

    Thomas algorithm on the chain rows ``1..m-1`` with two right-hand sides (``-R`` and
    the border column of ``q_in``), then one Schur-complement scalar for ``q_in``; the
    matrix entries are formed on the fly from the ring Jacobian. The factors (reciprocal
    pivots in W_INV with the Schur pivot in ``work[W_INV, 0]``, multipliers in W_CP, border
    solution in W_WW) stay in ``work`` for :func:`sweep`. Elimination and first right-hand
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
    if second_order_in(bp):
        A = _in_coef(hg, bp)
        di0 = A - hg * jd[0]
        r0 = -R[m] - A * R[0]
    dio = M[jo] - hg * jd[jo]
    ro = -R[jo]
    if second_order_out(bp):
        A = _out_coef(hg, bp)
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
    if second_order_in(bp):
        D[m] = (D[0] + R[0]) / hg
    if second_order_out(bp):
        D[m + 1] = (D[n + 1] + R[n + 1]) / hg


@njit(cache=True, error_model="numpy")
def sweep(n, hg, R, work, bp, D):
    """Solve ``(M - hg J) D = -R`` with the factors left in ``work`` by the last
    :func:`solve` (same ``hg`` and Jacobian); same operations on the right-hand side."""
    m = 2 * n + 2
    jo = n + 1
    jl = work[W_JLO]
    ju = work[W_JUP]
    cp = work[W_CP]
    inv_p = work[W_INV]
    z = work[W_ZZ]
    w = work[W_WW]
    r0 = -R[0]
    if second_order_in(bp):
        r0 = -R[m] - _in_coef(hg, bp) * R[0]
    ro = -R[jo]
    if second_order_out(bp):
        ro = -R[m + 1] - _out_coef(hg, bp) * R[jo]
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
def wrms(v, y, atolv, rtol, n_eff) -> float:
    """Weighted RMS norm ``sqrt(sum (v_i / (atol_i + rtol |y_i|))^2 / n_eff)``; ``n_eff``
    counts the live components (unused velocity slots hold 0)."""
    s = 0.0
    for i in range(v.shape[0]):
        wi = atolv[i] + rtol * abs(y[i])
        r = v[i] / wi
        s += r * r
    return math.sqrt(s / n_eff)
