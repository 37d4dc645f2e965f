"""Right-hand side and analytic Jacobian of the distributed tendon-sheath model.

Internal numerics of :mod:`capstan.models.distributed.model`; all functions are ``@njit(cache=True)``
and work on preallocated arrays.

State layout (``m = 2N + 2`` ring entries plus two velocity slots)::

    y[0]            q_in   [rad]   input pulley angle
    y[1 .. N]       u_1 .. u_N     upper-cable internal node displacements [m]
    y[N+1]          q_out  [rad]   output pulley angle
    y[N+2 .. 2N+1]  u_{N+3} .. u_{2N+2}  lower-cable internal node displacements [m]
    y[m]            dq_in  [rad/s] (state only in MOTOR input mode, else unused)
    y[m+1]          dq_out [rad/s] (state only with output inertia, else unused)

Node displacements are measured from the initial (pretensioned) positions. The first
``m`` entries form a ring: segment ``j`` joins ring entry ``j`` (upstream, paper node
``i-1``) and ring entry ``j+1 mod m`` (paper node ``i``), so segment ``j`` is the paper's
``f_{j,j+1}`` for the upper cable (``j = 0..N``) and ``f_{j+1,j+2}`` for the lower cable
(``j = N+1..2N+1``). The cable-end displacement of a pulley is ``r * q`` (arc length;
the paper's eq (9) prints ``q / r``, which is dimensionally inconsistent and would not
give the configured torsional stiffness).

Segment tension (optional cubic hardening, ``cc`` per segment elongation squared)::

    f_j = k * d * (1 + cc * d^2),   d = d0_j + disp(j) - disp(j+1)

with ``d0_j`` the elongation at the initial state (from the initial tensions).

Node law (eq 3, 11-13): ``b_i du_i/dt = g_i = F - fric``, ``F = f_a - f_b``,
``N_i = mu_i theta_i (f_a + f_b) / 2``, ``eps = F / N_i``,
``fric = N_i eps / (1 + |eps|^p)^(1/p)``, evaluated without overflow.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# bp (boundary/physics parameter vector) layout
BP_IN_MODE = 0      # 0 torque (first order), 1 motor (second order)
BP_B_IN = 1         # Nm s/rad, first-order input damping
BP_J_M = 2          # kg m^2
BP_B_M = 3          # Nm s/rad
BP_OUT_MODE = 4     # 0 testbed massless, 1 testbed with inertia, 2 link
BP_K_OUT = 5        # Nm/rad
BP_B_OUT = 6        # Nm s/rad
BP_J_OUT = 7        # kg m^2 (testbed inertia or link inertia)
BP_B_LINK = 8       # Nm s/rad
BP_MGL = 9          # Nm
BP_R_IN = 10        # m
BP_R_OUT = 11       # m
BP_K_SEG = 12       # N/m segment stiffness
BP_CC = 13          # 1/m^2 cubic coefficient on segment elongation
BP_MU = 14          # friction coefficient
BP_P = 15           # smoothness exponent
BP_SIZE = 16

OUT_TESTBED_MASSLESS = 0
OUT_TESTBED_INERTIA = 1
OUT_LINK = 2

# For p >= 100: below |eps| = 0.65, |eps|^p < 2e-19 and g = F (1 - (1 + |eps|^p)^(-1/p))
# ~ F |eps|^p / p is below the rounding of F -> exact stick (g and slopes 0); above
# |eps| = 1.55, |eps|^-p < 1e-19 -> exact Coulomb sliding. Results are unchanged to
# rounding; the cut-offs only skip the power and logarithm evaluations.
_EPS_STICK = 0.65
_EPS_SLIDE = 1.55


@njit(cache=True)
def _pow_p(a: float, p: float) -> float:
    """``a ** p`` for 0 <= a <= 1; exact repeated squaring for the default p = 100."""
    if p == 100.0:
        a2 = a * a
        a4 = a2 * a2
        a8 = a4 * a4
        a16 = a8 * a8
        a32 = a16 * a16
        return a32 * a32 * a32 * a4
    if a <= 0.0:
        return 0.0
    return math.exp(p * math.log(a))


@njit(cache=True)
def _expm1_neg(x: float) -> float:
    """``expm1(-x)`` for 0 <= x <= ln(2)/p; 5-term series when x < 0.015 (error < 1e-12)."""
    if x < 0.015:
        return -x * (1.0 - 0.5 * x * (1.0 - x * (1.0 / 3.0) * (1.0 - 0.25 * x * (1.0 - 0.2 * x))))
    return math.expm1(-x)


@njit(cache=True)
def node_law(f_a: float, f_b: float, c_n: float, p: float) -> tuple:
    """Net force on a node and its partial derivatives.

    :param f_a: upstream segment tension [N]; :param f_b: downstream segment tension [N].
    :param c_n: ``mu * theta_i / 2`` (normal-force factor, already scaled), >= 0.
    :param p: smoothness exponent.
    :returns: ``(g, dg/df_a, dg/df_b)`` with ``g = (f_a - f_b) - f_fric`` [N].
    """
    F = f_a - f_b
    N = c_n * (f_a + f_b)
    if c_n <= 0.0 or N <= 0.0:
        return F, 1.0, -1.0
    eps = F / N
    a = abs(eps)
    sgn = 1.0 if eps >= 0.0 else -1.0
    if a < _EPS_STICK and p >= 100.0:
        # a^p < 0.65^100 ~ 2e-19: g = F (1 - (1+a^p)^(-1/p)) and its slopes vanish
        return 0.0, 0.0, 0.0
    elif a <= 1.0:
        t = _pow_p(a, p)
        l1 = t * (1.0 - 0.5 * t) if t < 1e-8 else math.log1p(t)
        em = _expm1_neg(l1 / p)
        # s = (1+t)^(-1/p) = 1 + em;  g = F (1 - s);  dpsi/deps = s / (1 + t)
        g = -F * em
        r = 1.0 / (1.0 + t)
        phi_F = (t - em) * r
        phi_N = -eps * (t * r) * (1.0 + em)
    elif a > _EPS_SLIDE and p >= 100.0:
        g = F - N * sgn
        phi_F = 1.0          # 1 - a^-(p+1) (...) with a^-p < 1e-19
        phi_N = -sgn
    else:
        ia = 1.0 / a
        tp = _pow_p(ia, p)
        l1 = tp * (1.0 - 0.5 * tp) if tp < 1e-8 else math.log1p(tp)
        s = 1.0 + _expm1_neg(l1 / p)         # (1 + a^-p)^(-1/p)
        g = F - N * sgn * s
        r = s / (1.0 + tp)
        phi_F = 1.0 - (tp * ia) * r
        phi_N = -sgn * r
    return g, phi_F + phi_N * c_n, -phi_F + phi_N * c_n


@njit(cache=True, inline="always")
def elongation(y, j: int, n: int, d0, r_in: float, r_out: float) -> float:
    """Elongation [m] of ring segment ``j`` (joining ring entries ``j`` and ``j+1 mod m``)."""
    m = 2 * n + 2
    if j == 0:
        return d0[0] + r_in * y[0] - y[1]
    if j == n:
        return d0[j] + y[j] - r_out * y[j + 1]
    if j == n + 1:
        return d0[j] + r_out * y[j] - y[j + 1]
    if j == m - 1:
        return d0[j] + y[j] - r_in * y[0]
    return d0[j] + y[j] - y[j + 1]


@njit(cache=True)
def segment_forces(y, n, d0, bp, f_seg):
    """Segment tensions [N] of state ``y`` into ``f_seg`` (m,)."""
    r_in = bp[BP_R_IN]
    r_out = bp[BP_R_OUT]
    k = bp[BP_K_SEG]
    cc = bp[BP_CC]
    for j in range(2 * n + 2):
        d = elongation(y, j, n, d0, r_in, r_out)
        f_seg[j] = k * d if cc == 0.0 else k * d * (1.0 + cc * d * d)


@njit(cache=True)
def eval_system(y, u_Nm, text_Nm, n, d0, c_node, b_node, bp,
                f_seg, kt_seg, F, j_lo, j_di, j_up):
    """Evaluate ``F(y)`` of ``M dy/dt = F(y)`` and the ring Jacobian.

    :param y: state (m+2,). :param u_Nm: input torque (tau_in or tau_m) [Nm].
    :param text_Nm: external torque on the link [Nm] (LINK mode only).
    :param n: number of internal nodes per cable N.
    :param d0: (m,) initial segment elongations [m].
    :param c_node: (m,) ``mu * mu_scale * theta / 2`` per ring entry (0 at pulleys).
    :param b_node: (m,) node damping per ring entry [N s/m] (unused at pulleys).
    :param bp: parameter vector (see ``BP_*``).
    :param f_seg, kt_seg: (m,) outputs: segment tensions [N], tangent stiffnesses [N/m].
    :param F: (m+2,) output right-hand side. For the pulley ring entries with a
        velocity state ``F`` is the velocity; the velocity slot holds the net torque.
    :param j_lo, j_di, j_up: (m,) outputs: derivatives of the *force/torque* balance of
        ring entry ``j`` w.r.t. ring entries ``j-1``, ``j``, ``j+1`` (cyclic). For pulleys
        this is the net torque's derivative (velocity terms excluded).
    """
    m = 2 * n + 2
    r_in = bp[BP_R_IN]
    r_out = bp[BP_R_OUT]
    k = bp[BP_K_SEG]
    cc = bp[BP_CC]
    p = bp[BP_P]
    for j in range(m):
        d = elongation(y, j, n, d0, r_in, r_out)
        if cc == 0.0:
            f_seg[j] = k * d
            kt_seg[j] = k
        else:
            f_seg[j] = k * d * (1.0 + cc * d * d)
            kt_seg[j] = k * (1.0 + 3.0 * cc * d * d)
    # internal nodes
    for j in range(1, m):
        if j == n + 1:
            continue
        g, ga, gb = node_law(f_seg[j - 1], f_seg[j], c_node[j], p)
        F[j] = g
        s_lo = r_in if j == 1 else (r_out if j == n + 2 else 1.0)
        s_up = r_out if j == n else (r_in if j == m - 1 else 1.0)
        j_lo[j] = ga * kt_seg[j - 1] * s_lo
        j_di[j] = -ga * kt_seg[j - 1] + gb * kt_seg[j]
        j_up[j] = -gb * kt_seg[j] * s_up
    # input pulley: net torque u - tau_cable_in, tau_cable_in = r_in (f_0 - f_{m-1})
    tau_in = r_in * (f_seg[0] - f_seg[m - 1])
    net_in = u_Nm - tau_in
    j_di[0] = -r_in * r_in * (kt_seg[0] + kt_seg[m - 1])
    j_up[0] = r_in * kt_seg[0]
    j_lo[0] = r_in * kt_seg[m - 1]
    if bp[BP_IN_MODE] == 0.0:
        F[0] = net_in
        F[m] = 0.0
    else:
        F[0] = y[m]
        F[m] = net_in - bp[BP_B_M] * y[m]
    # output pulley: tau_out = r_out (f_N - f_{N+1})
    jo = n + 1
    tau_out = r_out * (f_seg[n] - f_seg[n + 1])
    dt_dq = -r_out * r_out * (kt_seg[n] + kt_seg[n + 1])
    j_lo[jo] = r_out * kt_seg[n]
    j_up[jo] = r_out * kt_seg[n + 1]
    mode = int(bp[BP_OUT_MODE])
    q = y[jo]
    if mode == OUT_TESTBED_MASSLESS:
        F[jo] = tau_out - bp[BP_K_OUT] * q
        j_di[jo] = dt_dq - bp[BP_K_OUT]
        F[m + 1] = 0.0
    elif mode == OUT_TESTBED_INERTIA:
        F[jo] = y[m + 1]
        F[m + 1] = tau_out - bp[BP_K_OUT] * q - bp[BP_B_OUT] * y[m + 1]
        j_di[jo] = dt_dq - bp[BP_K_OUT]
    else:
        mgl = bp[BP_MGL]
        F[jo] = y[m + 1]
        F[m + 1] = tau_out - mgl * math.sin(q) + text_Nm - bp[BP_B_LINK] * y[m + 1]
        j_di[jo] = dt_dq - mgl * math.cos(q)
    return tau_in, tau_out


@njit(cache=True)
def mass_diag(n, b_node, bp, M):
    """Fill the diagonal mass matrix ``M`` (m+2,) of ``M dy/dt = F(y)``."""
    m = 2 * n + 2
    for j in range(m):
        M[j] = b_node[j]
    if bp[BP_IN_MODE] == 0.0:
        M[0] = bp[BP_B_IN]
        M[m] = 1.0
    else:
        M[0] = 1.0
        M[m] = bp[BP_J_M]
    mode = int(bp[BP_OUT_MODE])
    if mode == OUT_TESTBED_MASSLESS:
        M[n + 1] = bp[BP_B_OUT]
        M[m + 1] = 1.0
    else:
        M[n + 1] = 1.0
        M[m + 1] = bp[BP_J_OUT]


@njit(cache=True)
def min_tension(f_seg) -> tuple:
    """Return ``(index, value)`` of the smallest segment tension."""
    jm = 0
    fm = f_seg[0]
    for j in range(1, f_seg.shape[0]):
        if f_seg[j] < fm:
            fm = f_seg[j]
            jm = j
    return jm, fm


def rhs_numpy(y: np.ndarray, u_Nm: float, text_Nm: float, n: int, d0: np.ndarray,
              c_node: np.ndarray, b_node: np.ndarray, bp: np.ndarray) -> np.ndarray:
    """Plain-numpy ``dy/dt`` of the same equations (reference for scipy / tests).

    Written independently of :func:`eval_system` (vectorised, direct formulas).
    """
    m = 2 * n + 2
    r_in, r_out, k, cc, p = bp[BP_R_IN], bp[BP_R_OUT], bp[BP_K_SEG], bp[BP_CC], bp[BP_P]
    disp = y[:m].copy()
    disp[0] *= r_in
    disp[n + 1] *= r_out
    d = d0 + disp - np.roll(disp, -1)
    f = k * d * (1.0 + cc * d * d)
    dy = np.zeros(m + 2)
    idx = np.array([j for j in range(1, m) if j != n + 1])
    fa, fb = f[idx - 1], f[idx]
    Fn = fa - fb
    Nn = c_node[idx] * (fa + fb)
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        eps = np.where(Nn > 0, Fn / np.where(Nn > 0, Nn, 1.0), 0.0)
        a = np.abs(eps)
        big = a > 1.0
        s_small = np.power(1.0 + np.power(np.minimum(a, 1.0), p), -1.0 / p)
        s_big = np.power(1.0 + np.power(np.maximum(a, 1.0), -p), -1.0 / p)
        fric = np.where(big, Nn * np.sign(eps) * s_big, Fn * s_small)
    fric = np.where(Nn > 0, fric, 0.0)
    dy[idx] = (Fn - fric) / b_node[idx]
    tau_in = r_in * (f[0] - f[m - 1])
    tau_out = r_out * (f[n] - f[n + 1])
    if bp[BP_IN_MODE] == 0.0:
        dy[0] = (u_Nm - tau_in) / bp[BP_B_IN]
    else:
        dy[0] = y[m]
        dy[m] = (u_Nm - tau_in - bp[BP_B_M] * y[m]) / bp[BP_J_M]
    mode = int(bp[BP_OUT_MODE])
    q = y[n + 1]
    if mode == OUT_TESTBED_MASSLESS:
        dy[n + 1] = (tau_out - bp[BP_K_OUT] * q) / bp[BP_B_OUT]
    elif mode == OUT_TESTBED_INERTIA:
        dy[n + 1] = y[m + 1]
        dy[m + 1] = (tau_out - bp[BP_K_OUT] * q - bp[BP_B_OUT] * y[m + 1]) / bp[BP_J_OUT]
    else:
        dy[n + 1] = y[m + 1]
        dy[m + 1] = (tau_out - bp[BP_MGL] * np.sin(q) + text_Nm - bp[BP_B_LINK] * y[m + 1]) / bp[BP_J_OUT]
    return dy
