"""Test oracle: a second, compiled implementation of the paper's distributed dual-cable
tendon-sheath model (eqs 2-13, 23), written from the paper and design.md alone -- no code of
``capstan.models`` is imported or copied. Fast enough to generate 1 kHz runs for the closure
tests (tests/independent_runs.py adds the effects and the sensors).

Formulation (this module's own coordinates, not the paper's node numbering): each cable
(``UPPER``, ``LOWER``) is a chain of nodes j = 0..N+1 in routing order from the input pulley
(j = 0) to the output pulley (j = N+1); ``x_j`` [m] is node j's displacement along the cable,
positive towards the input end. Segment j (between nodes j and j+1) has tension
``T_j = T0_j s_T(t) + k (x_j - x_{j+1})`` with ``k = (N+1) K_c / (2 r_in r_out)`` (N+1
springs in series give the cable K_c / (2 r^2), design.md §1). Boundary nodes follow the
pulleys: ``x_0 = sigma rho_in q_in``, ``x_{N+1} = sigma rho_out q_out`` with sigma = +1 for
the upper and -1 for the lower cable.  Internal node j (massless, eq 3):
``b_j v_j + c1 v_j + c2 v_j |v_j| = g_j - F_j``, ``g_j = T_{j-1} - T_j``, with the smooth
Coulomb law (13) ``F = g (1 + |g / n|^p)^(-1/p)`` on the capacity ``n = mu theta_j (1 + a_j)
(T_{j-1} + T_j) / 2`` (eq 11). ``c1``, ``c2`` (0 in the paper) are a sheath drag in the
node's own sliding speed; ``a_j`` a junction-ageing state (tests/independent_runs.py).
The quadratic is solved for v in closed form, so the node rate is explicit in the state.

Input (eq 2): TORQUE ``b_in dq_in = tau - tau_c``; MOTOR ``J_m ddq_in + b_m dq_in = tau_m -
tau_c``, ``tau_c = r_in (T_up,0 - T_lo,0)``.  Output (eq 4 with the design.md errata):
TESTBED ``b_out dq_out + k_out q_out = tau_out``; LINK ``J_l ddq + b_l dq + mgl sin q =
tau_out``; ``tau_out = r_out (T_up,N - T_lo,N)`` (eq 6, errata: the difference).

Readings of the paper (the options below name both; tests/test_independent_plant.py runs both
where it is cheap):

* eq 9: ``rho = r`` (arc length, ``EQ9_ARC``: the only one giving the configured K_c) or
  ``rho = 1 / r`` as printed (``EQ9_PRINTED``: a stiffness K_c / r^4).
* theta_i (eq 11, "the bending over segment i" with N nodes and N+1 segments):
  ``THETA_CELLS`` node i takes the i-th of N equal arc-length cells (the bends sum to theta);
  ``THETA_SEGMENTS`` N+1 equal segments between nodes, node i takes half of each adjacent
  segment (the halves at the pulleys carry no node: the sum is short by one segment).
* node damping, Table 3 b_l = 1e-3 N s/mm: 1 N s/m per node whatever N (``b_node``), or a
  cable damping split over the nodes (``b_node = b_total / N``): the caller chooses.
* b_in, Table 3 "1e-4 Nms/mm": 1e-4 N m s/rad (the unit a typo), or per mm of cable travel
  at the 40 mm pulley, 4e-3 N m s/rad. p = 100 (Fig. 3, "applied throughout").

Integration: fixed-step BDF2 (first step backward Euler), Newton with the exact Jacobian
(the tensions are linear in the state, the node laws are differentiated by hand), ``substeps``
steps per sample (256 in the first interval); inputs piecewise linear between samples, exogenous parameters (pretension
scale, bend scale, ageing drive) evaluated at the step end. The ageing state is advanced after
each step, implicitly in itself with the step's converged node speeds (operator splitting).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

EQ9_ARC, EQ9_PRINTED = 0, 1
THETA_CELLS, THETA_SEGMENTS = 0, 1
TORQUE, MOTOR = 0, 1
TESTBED, LINK = 0, 1


def node_bends(kappa_1_m, length_m: float, n_nodes: int, reading: int = THETA_CELLS) -> np.ndarray:
    """Per-node bending angles [rad] from a curvature profile ``kappa_1_m(s)`` [1/m] over the
    arc length [0, length_m], integrated (trapezoid, 200 points per piece) per the reading."""
    def integral(a: float, b: float) -> float:
        s = np.linspace(a, b, 201)
        k = np.abs(kappa_1_m(s))
        return float(np.sum((k[1:] + k[:-1]) * 0.5 * np.diff(s)))
    if reading == THETA_CELLS:
        e = np.linspace(0.0, length_m, n_nodes + 1)
        return np.array([integral(e[i], e[i + 1]) for i in range(n_nodes)])
    e = np.linspace(0.0, length_m, n_nodes + 2)
    seg = np.array([integral(e[i], e[i + 1]) for i in range(n_nodes + 1)])
    return 0.5 * (seg[:-1] + seg[1:])


def capstan_field(theta_nodes: np.ndarray, T_in_N: float, T_out_N: float, mu: float) -> np.ndarray:
    """Eq (23) on the nodes: segment j's pretension [N] is the larger of the decay from the
    input fixture (bending passed before it) and from the output fixture (bending after it)."""
    before = np.concatenate(([0.0], np.cumsum(theta_nodes)))
    after = before[-1] - before
    return np.maximum(T_in_N * np.exp(-mu * before), T_out_N * np.exp(-mu * after))


@dataclass
class Plant:
    """Parameters (SI). ``theta_*``: (N,) node bends in routing order input -> output;
    ``T0_*``: (N+1,) segment pretensions [N] in the same order."""

    theta_up: np.ndarray
    theta_lo: np.ndarray
    T0_up: np.ndarray
    T0_lo: np.ndarray
    K_c: float = 240.0
    mu: float = 0.052
    p: float = 100.0
    r_in: float = 0.04
    r_out: float = 0.04
    b_node: float = 1.0
    drag_c1: float = 0.0          # extra linear node drag [N s/m]
    drag_c2: float = 0.0          # quadratic node drag [N s^2/m^2]
    eq9: int = EQ9_ARC
    input_mode: int = TORQUE
    b_in: float = 1e-4
    J_m: float = 0.73
    b_m: float = 2.0
    output_mode: int = TESTBED
    k_out: float = 20.0
    b_out: float = 2.0
    J_l: float = 0.17
    b_l: float = 0.02
    mgl: float = 3.78

    @property
    def n(self) -> int:
        return len(self.theta_up)

    @property
    def k_seg(self) -> float:
        return (self.n + 1) * self.K_c / (2.0 * self.r_in * self.r_out)


def layout(P: Plant) -> tuple[int, int, int, int]:
    """State indices: (i_qin, i_x0, i_qout, ny); motor and link add a rate after their angle."""
    i_x0 = 2 if P.input_mode == MOTOR else 1
    i_qout = i_x0 + 2 * P.n
    ny = i_qout + (2 if P.output_mode == LINK else 1)
    return 0, i_x0, i_qout, ny


def tension_matrix(P: Plant) -> np.ndarray:
    """D (2(N+1) x ny): segment tensions T = T0 s_T + D y; rows upper 0..N then lower 0..N."""
    N = P.n
    _, i_x0, i_qout, ny = layout(P)
    rho_in = P.r_in if P.eq9 == EQ9_ARC else 1.0 / P.r_in
    rho_out = P.r_out if P.eq9 == EQ9_ARC else 1.0 / P.r_out
    D = np.zeros((2 * (N + 1), ny))
    for c, sg in ((0, 1.0), (1, -1.0)):
        for j in range(N + 1):
            row = c * (N + 1) + j
            for node, s in ((j, 1.0), (j + 1, -1.0)):
                if node == 0:
                    D[row, 0] += s * sg * rho_in
                elif node == N + 1:
                    D[row, i_qout] += s * sg * rho_out
                else:
                    D[row, i_x0 + c * N + node - 1] += s
    return D * P.k_seg


@njit(cache=True)
def _coulomb(g: float, n: float, p: float) -> tuple[float, float, float]:
    """Eq (13): F = g (1 + |g/n|^p)^(-1/p) and dF/dg, dF/dn, overflow-free for large p."""
    if n <= 0.0:
        return 0.0, 0.0, 0.0
    e = abs(g) / n
    if e >= 1.0:
        q = e ** (-p)
        G = (1.0 + q) ** (-1.0 / p) / e
        w = 1.0 / (1.0 + q)
    else:
        q = e ** p
        G = (1.0 + q) ** (-1.0 / p)
        w = q / (1.0 + q)
    return g * G, G * (1.0 - w), G * w * g / n


@njit(cache=True)
def _drag_speed(h: float, b: float, c2: float) -> tuple[float, float]:
    """v with b v + c2 v |v| = h, and dv/dh."""
    if c2 == 0.0:
        return h / b, 1.0 / b
    root = np.sqrt(b * b + 4.0 * c2 * abs(h))
    v = np.sign(h) * (root - b) / (2.0 * c2)
    return v, 1.0 / root


@njit(cache=True)
def _rhs(y, tau, T0s, mth, D, N, i_x0, i_qout, modes, sc, with_jac, J, v_out):
    """Right-hand side (and its Jacobian into J if with_jac); node speeds into v_out.
    mth: (2N,) mu theta_j (1 + a_j); sc: scalars (see _pack)."""
    p, b_node, c1, c2 = sc[0], sc[1], sc[2], sc[3]
    r_in, r_out, b_in, J_m, b_m = sc[4], sc[5], sc[6], sc[7], sc[8]
    k_out, b_out, J_l, b_l, mgl = sc[9], sc[10], sc[11], sc[12], sc[13]
    T = T0s + D @ y
    ny = y.shape[0]
    f = np.zeros(ny)
    if with_jac:
        J[:, :] = 0.0
    b = b_node + c1
    for c in range(2):
        for j in range(1, N + 1):
            a = c * (N + 1) + j - 1          # segment before node j (the next is a + 1)
            g = T[a] - T[a + 1]
            m = 0.5 * mth[c * N + j - 1]
            F, Fg, Fn = _coulomb(g, m * (T[a] + T[a + 1]), p)
            v, dv = _drag_speed(g - F, b, c2)
            i = i_x0 + c * N + j - 1
            f[i] = v
            v_out[c * N + j - 1] = v
            if with_jac:
                J[i, :] = dv * ((1.0 - Fg) * (D[a] - D[a + 1]) - Fn * m * (D[a] + D[a + 1]))
    tc = r_in * (T[0] - T[N + 1])
    if modes[0] == 0:
        f[0] = (tau - tc) / b_in
        if with_jac:
            J[0, :] = -r_in * (D[0] - D[N + 1]) / b_in
    else:
        f[0] = y[1]
        f[1] = (tau - b_m * y[1] - tc) / J_m
        if with_jac:
            J[0, 1] = 1.0
            J[1, :] = -r_in * (D[0] - D[N + 1]) / J_m
            J[1, 1] -= b_m / J_m
    to = r_out * (T[N] - T[2 * N + 1])
    dto = r_out * (D[N] - D[2 * N + 1])
    if modes[1] == 0:
        f[i_qout] = (to - k_out * y[i_qout]) / b_out
        if with_jac:
            J[i_qout, :] = dto / b_out
            J[i_qout, i_qout] -= k_out / b_out
    else:
        w = y[i_qout + 1]
        f[i_qout] = w
        f[i_qout + 1] = (to - b_l * w - mgl * np.sin(y[i_qout])) / J_l
        if with_jac:
            J[i_qout, i_qout + 1] = 1.0
            J[i_qout + 1, :] = dto / J_l
            J[i_qout + 1, i_qout] -= mgl * np.cos(y[i_qout]) / J_l
            J[i_qout + 1, i_qout + 1] -= b_l / J_l
    return f


@njit(cache=True)
def _march(y0, t, u, T0, s_T, bend, age_drive, mu_theta, D, N, i_x0, i_qout, modes, sc, substeps,
           age_tau_s, age_s0_m, age_amp, Y, V):
    """BDF2 over the samples t (inputs u, pretension scale s_T, bend scale bend (n_t, 2N),
    ageing drive age_drive in [0, 1]); states into Y (n_t, ny), node speeds into V (n_t, 2N).
    Returns the number of steps whose Newton iteration did not converge (0 expected)."""
    ny = y0.shape[0]
    y = y0.copy()
    y_prev = y0.copy()
    a = np.zeros(2 * N)
    v = np.zeros(2 * N)
    J = np.zeros((ny, ny))
    Jd = np.zeros((ny, ny))
    eye = np.eye(ny)
    Y[0] = y
    first = True
    bad = 0
    for s in range(t.shape[0] - 1):
        # the first interval finely: a state built from the pretension field is not at rest
        # (us-scale transients); what a coarse first step gets wrong there stays in the run
        n_sub = 256 if s == 0 else substeps
        h = (t[s + 1] - t[s]) / n_sub
        if s == 1:
            first = True            # the step changes: BDF2 restarts with one backward-Euler step
        for m in range(n_sub):
            w1 = (m + 1.0) / n_sub
            tau = u[s] + w1 * (u[s + 1] - u[s])
            T0s = T0 * (s_T[s] + w1 * (s_T[s + 1] - s_T[s]))
            mth = mu_theta * bend[s + 1] * (1.0 + a)
            if first:
                c_old = y.copy()
                gam = h
            else:
                c_old = (4.0 * y - y_prev) / 3.0
                gam = 2.0 * h / 3.0
            z = y.copy()
            fz = _rhs(z, tau, T0s, mth, D, N, i_x0, i_qout, modes, sc, True, J, v)
            r = z - c_old - gam * fz
            ok = False
            for it in range(60):
                for i in range(ny):
                    for k in range(ny):
                        Jd[i, k] = eye[i, k] - gam * J[i, k]
                dz = np.linalg.solve(Jd, -r)
                err = 0.0
                for i in range(ny):
                    tol = 1e-12 if i_x0 <= i < i_qout else 1e-10     # m (1 uN of tension); rad, rad/s
                    err = max(err, abs(dz[i]) / tol)
                # backtracking on the residual's norm (the node laws have kinks)
                r0 = np.sqrt(np.sum(r * r))
                lam = 1.0
                for _ in range(12):
                    zt = z + lam * dz
                    ft = _rhs(zt, tau, T0s, mth, D, N, i_x0, i_qout, modes, sc, True, J, v)
                    rt = zt - c_old - gam * ft
                    if np.sqrt(np.sum(rt * rt)) < r0 or lam < 1e-3 or err < 1.0:
                        break
                    lam *= 0.5
                z = zt
                r = rt
                if err < 1.0:
                    ok = True
                    break
            if not ok:
                bad += 1
            _rhs(z, tau, T0s, mth, D, N, i_x0, i_qout, modes, sc, False, J, v)
            y_prev = y
            y = z
            first = False
            if age_amp > 0.0:
                drive = age_drive[s] + w1 * (age_drive[s + 1] - age_drive[s])
                for i in range(2 * N):
                    a[i] = (a[i] + h * age_amp * drive / age_tau_s) / (
                        1.0 + h / age_tau_s + h * abs(v[i]) / age_s0_m)
        Y[s + 1] = y
        V[s + 1] = v
    return bad


def _pack(P: Plant) -> np.ndarray:
    return np.array([P.p, P.b_node, P.drag_c1, P.drag_c2, P.r_in, P.r_out, P.b_in, P.J_m, P.b_m,
                     P.k_out, P.b_out, P.J_l, P.b_l, P.mgl])


@dataclass
class Run:
    """Sampled outputs (SI): angles, rates, torques, the four fixture tensions
    (T_up_in, T_up_out, T_lo_out, T_lo_in) and all segment tensions (n_t, 2(N+1))."""

    t: np.ndarray
    q_in: np.ndarray
    dq_in: np.ndarray
    q_out: np.ndarray
    dq_out: np.ndarray
    tau_in: np.ndarray
    tau_out: np.ndarray
    fixture: np.ndarray
    T: np.ndarray
    y_end: np.ndarray
    newton_failures: int


def simulate(P: Plant, t: np.ndarray, u: np.ndarray, substeps: int = 2, y0: np.ndarray | None = None,
             s_T: np.ndarray | None = None, bend: np.ndarray | None = None, age_drive: np.ndarray | None = None,
             age_tau_s: float = 1.0, age_s0_m: float = 1e-4, age_amp: float = 0.0) -> Run:
    """Run the model over the samples ``t`` [s] with input ``u`` [Nm] (torque or motor torque).

    ``s_T`` (n_t,) scales the pretension field, ``bend`` (n_t, 2N) the node bends (default 1);
    the ageing state (``age_amp`` > 0) grows towards ``age_amp * age_drive`` with the time
    constant ``age_tau_s`` and is erased by node slip over ``age_s0_m`` [m].
    """
    t = np.ascontiguousarray(t, float)
    n_t = t.shape[0]
    N = P.n
    _, i_x0, i_qout, ny = layout(P)
    D = tension_matrix(P)
    T0 = np.concatenate([P.T0_up, P.T0_lo]).astype(float)
    one = np.ones(n_t)
    s_T = one if s_T is None else np.asarray(s_T, float)
    bend = np.ones((n_t, 2 * N)) if bend is None else np.asarray(bend, float)
    age_drive = np.zeros(n_t) if age_drive is None else np.asarray(age_drive, float)
    mu_theta = P.mu * np.concatenate([P.theta_up, P.theta_lo]).astype(float)
    y = np.zeros(ny) if y0 is None else np.asarray(y0, float).copy()
    Y = np.zeros((n_t, ny))
    V = np.zeros((n_t, 2 * N))
    modes = np.array([P.input_mode, P.output_mode], dtype=np.int64)
    bad = _march(y, t, np.asarray(u, float), T0, s_T, bend, age_drive, mu_theta, D, N, i_x0, i_qout, modes,
                 _pack(P), int(substeps), float(age_tau_s), float(age_s0_m), float(age_amp), Y, V)
    T = T0[None, :] * s_T[:, None] + Y @ D.T
    tau_in = P.r_in * (T[:, 0] - T[:, N + 1])
    tau_out = P.r_out * (T[:, N] - T[:, 2 * N + 1])
    q_in, q_out = Y[:, 0], Y[:, i_qout]
    if P.input_mode == MOTOR:
        dq_in = Y[:, 1]
    else:
        dq_in = (np.asarray(u, float) - tau_in) / P.b_in
    if P.output_mode == LINK:
        dq_out = Y[:, i_qout + 1]
    else:
        dq_out = (tau_out - P.k_out * q_out) / P.b_out
    fixture = np.column_stack([T[:, 0], T[:, N], T[:, 2 * N + 1], T[:, N + 1]])
    return Run(t, q_in, dq_in, q_out, dq_out, tau_in, tau_out, fixture, T, Y[-1].copy(), int(bad))
