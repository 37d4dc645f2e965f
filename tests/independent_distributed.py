"""Test oracle: an independent implementation of the paper's distributed dual-cable
tendon-sheath model, written from the paper and design.md alone (not from models/), used by
tests/test_distributed_vs_independent.py. Implements
eqs (2)-(13) with the design.md sign errata for (4) and (6), initial state from the
pretension field (23).  Plain numpy + scipy.solve_ivp.  SI units (m, N, rad).

Node numbering as in the paper: upper cable x_0 (input end) .. x_{N+1} (output end),
lower cable x_{N+2} (output end) .. x_{2N+3} (input end).  Segment tension
f_{i-1,i} = k (x_{i-1} - x_i).

State y = [q_in, x_1..x_N, x_{N+3}..x_{2N+2}, q_out]  (2N+2), boundary nodes from (9),
but with x = x(0) + r q (arc length), not q / r as printed in (9): the printed form is
dimensionally wrong and gives a static stiffness K_c / r^4 ... (only x = r q reproduces
the configured K_c with per-cable stiffness K_c/(2 r^2), design.md §1/§2).

Equations (massless, first order):
  (2)  b_in dq_in = tau_in - r_in (f_{0,1} - f_{2N+2,2N+3})
  (3)  b dx_i = f_{i-1,i} - f_{i,i+1} - f_fric,i
  (4') b_out dq_out = r_out (f_{N,N+1} - f_{N+2,N+3}) - k_out q_out      (errata)
  (6') tau_out = r_out (f_{N,N+1} - f_{N+2,N+3})                         (errata)
  (11) f_N,i = (f_{i-1,i} + f_{i,i+1}) theta_i / 2
  (13) f_fric,i = mu f_N eps / (1+|eps|^p)^(1/p),  eps = f_in,i / (mu f_N),
       f_in,i = f_{i-1,i} - f_{i,i+1}

Choices (defaults documented in models/distributed/params.py):
  k (segment) = (N+1) K_c / (2 r_in r_out);  b (per internal node) = 1.0 N s/m;
  p = 100;  b_in = 1e-3 Nm s/rad (torque mode: b_in dq_in = tau_in - tau_cable);
  testbed output massless, k_out = 20 Nm/rad, b_out = 2 Nm s/rad;
  theta_i = theta / N (uniform);  lower-cable arrays are given in routing order
  input -> output, i.e. reversed w.r.t. the paper's lower-node numbering.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp


def pretension_field(theta_nodes: np.ndarray, T_in: float, T_out: float, mu: float) -> np.ndarray:
    """Eq (23) discretised: segment tensions (N+1, routing order input->output).  Segment j
    has passed cum_j = sum_{i<j} theta_i of bending from the input end; the field is the
    larger of the two profiles decaying from each fixture (minimum at s_min, eq 24)."""
    cum = np.concatenate(([0.0], np.cumsum(theta_nodes)))
    return np.maximum(T_in * np.exp(-mu * cum), T_out * np.exp(-mu * (cum[-1] - cum)))


@dataclass
class Params:
    theta_upper: np.ndarray        # (N,) routing order input->output
    theta_lower: np.ndarray        # (N,) routing order input->output
    T_upper: np.ndarray            # (N+1,) initial segment tensions, input->output
    T_lower: np.ndarray            # (N+1,)
    K_c: float = 240.0
    mu: float = 0.052
    p: float = 100.0
    r_in: float = 0.04
    r_out: float = 0.04
    b_node: float = 1.0
    b_in: float = 1e-3
    k_out: float = 20.0
    b_out: float = 2.0


class IndepModel:
    """Dense numpy ODE of the model (state: q_in, internal node displacements, q_out),
    integrated by scipy's implicit solvers with an analytic Jacobian."""

    def __init__(self, P: Params):
        self.P = P
        N = len(P.theta_upper)
        self.N = N
        self.k = (N + 1) * P.K_c / (2.0 * P.r_in * P.r_out)
        nX = 2 * N + 4
        nS = 2 * N + 2            # segments
        ny = 2 * N + 2
        # ---- initial node displacements from the pretension field ----
        k = self.k
        X0 = np.zeros(nX)
        # upper: x_{N+1}=0, x_{j} = x_{j+1} + T_u[j]/k  (segment j between x_j and x_{j+1})
        for j in range(N, -1, -1):
            X0[j] = X0[j + 1] + P.T_upper[j] / k
        # lower: nodes x_{N+2+m}, m=0..N+1 (m=0 output end).  Segment m (between x_{N+2+m}
        # and x_{N+3+m}) is routing index N-m.  Set x_{2N+3}=0 and go backwards.
        X0[2 * N + 3] = 0.0
        for m in range(N, -1, -1):
            X0[N + 2 + m] = X0[N + 3 + m] + P.T_lower[N - m] / k
        self.X0 = X0
        # ---- map y -> X :  X = Pm @ y + c ----
        Pm = np.zeros((nX, ny))
        c = np.zeros(nX)
        Pm[0, 0] = P.r_in; c[0] = X0[0]
        Pm[N + 1, ny - 1] = P.r_out; c[N + 1] = X0[N + 1]
        Pm[N + 2, ny - 1] = P.r_out; c[N + 2] = X0[N + 2]
        Pm[2 * N + 3, 0] = P.r_in; c[2 * N + 3] = X0[2 * N + 3]
        for i in range(1, N + 1):
            Pm[i, i] = 1.0                       # x_i, state index i
        for m in range(1, N + 1):
            Pm[N + 2 + m, N + m] = 1.0           # x_{N+2+m}, state index N+m
        self.Pm, self.c = Pm, c
        # ---- segment tensions f = k A X, global segment list ----
        A = np.zeros((nS, nX))
        for j in range(N + 1):                   # upper segment j: x_j - x_{j+1}
            A[j, j] = 1.0; A[j, j + 1] = -1.0
        for m in range(N + 1):                   # lower segment m: x_{N+2+m} - x_{N+3+m}
            A[N + 1 + m, N + 2 + m] = 1.0; A[N + 1 + m, N + 3 + m] = -1.0
        self.Af = k * A @ Pm                     # f = Af y + fc
        self.fc = k * A @ c
        # ---- per internal node: prev/next segment, theta ----
        prev, nxt, th = [], [], []
        for i in range(1, N + 1):
            prev.append(i - 1); nxt.append(i); th.append(P.theta_upper[i - 1])
        for m in range(1, N + 1):
            prev.append(N + 1 + m - 1); nxt.append(N + 1 + m); th.append(P.theta_lower[N - m])
        prev, nxt = np.array(prev), np.array(nxt)
        self.th = np.array(th)
        Sm = np.zeros((2 * N, nS)); Nm = np.zeros((2 * N, nS))
        Sm[np.arange(2 * N), prev] += 1.0; Sm[np.arange(2 * N), nxt] -= 1.0
        Nm[np.arange(2 * N), prev] += 0.5; Nm[np.arange(2 * N), nxt] += 0.5
        Nm *= (P.mu * self.th)[:, None]          # n = mu f_N
        self.Sy = Sm @ self.Af; self.Sc = Sm @ self.fc
        self.Ny = Nm @ self.Af; self.Nc = Nm @ self.fc
        # torque rows
        e = np.zeros(nS); e[0] = P.r_in; e[2 * N + 1] = -P.r_in
        self.Tin_y = e @ self.Af; self.Tin_c = e @ self.fc
        e = np.zeros(nS); e[N] = P.r_out; e[N + 1] = -P.r_out
        self.Tout_y = e @ self.Af; self.Tout_c = e @ self.fc
        self.y0 = np.zeros(ny)
        self.y0[1:N + 1] = X0[1:N + 1]
        self.y0[N + 1:2 * N + 1] = X0[N + 3:2 * N + 3]
        self.ny = ny

    # friction law (13) and its partial derivatives, overflow-safe for p = 100
    def _fric(self, s, n):
        p = self.P.p
        if self.P.mu == 0.0:
            z = np.zeros_like(s)
            return z, z, z
        a = np.abs(s) / n
        la = p * np.log(np.maximum(a, 1e-300))           # log |eps|^p
        sp = np.logaddexp(0.0, la)                      # log(1+|eps|^p)
        G = np.exp(-sp / p)
        w = np.exp(la - sp)                             # |eps|^p/(1+|eps|^p)
        F = s * G
        dFds = G * (1.0 - w)
        dFdn = G * (s / n) * w
        return F, dFds, dFdn

    def tau_in_fun(self, t_s, u):
        t_s = np.asarray(t_s); u = np.asarray(u)
        return lambda t: np.interp(t, t_s, u)

    def rhs(self, t, y, tau_in):
        P = self.P
        s = self.Sy @ y + self.Sc
        n = self.Ny @ y + self.Nc
        F, _, _ = self._fric(s, n)
        dy = np.empty_like(y)
        dy[0] = (tau_in(t) - (self.Tin_y @ y + self.Tin_c)) / P.b_in
        dy[1:-1] = (s - F) / P.b_node
        dy[-1] = ((self.Tout_y @ y + self.Tout_c) - P.k_out * y[-1]) / P.b_out
        return dy

    def jac(self, t, y, tau_in=None):
        P = self.P
        s = self.Sy @ y + self.Sc
        n = self.Ny @ y + self.Nc
        _, dFds, dFdn = self._fric(s, n)
        J = np.empty((self.ny, self.ny))
        J[0] = -self.Tin_y / P.b_in
        J[1:-1] = (self.Sy - dFds[:, None] * self.Sy - dFdn[:, None] * self.Ny) / P.b_node
        J[-1] = self.Tout_y / P.b_out
        J[-1, -1] -= P.k_out / P.b_out
        return J

    def outputs(self, Y):
        """Y: (ny, nt).  Returns dict of tau_out, tau_in (cable torque), q_in, q_out, tensions."""
        f = self.Af @ Y + self.fc[:, None]
        return dict(tau_out=self.Tout_y @ Y + self.Tout_c, tau_in_cable=self.Tin_y @ Y + self.Tin_c,
                    q_in=Y[0], q_out=Y[-1], f=f)

    def simulate(self, t_s, u, method="Radau", rtol=1e-8, atol_x=1e-12, atol_q=1e-10, tau_fun=None,
                 y0=None, max_step=np.inf):
        tau = tau_fun if tau_fun is not None else self.tau_in_fun(t_s, u)
        atol = np.full(self.ny, atol_x); atol[0] = atol_q; atol[-1] = atol_q
        sol = solve_ivp(lambda t, y: self.rhs(t, y, tau), (t_s[0], t_s[-1]),
                        self.y0 if y0 is None else y0, method=method, t_eval=t_s, rtol=rtol, atol=atol,
                        jac=lambda t, y: self.jac(t, y), max_step=max_step)
        if not sol.success:
            raise RuntimeError(sol.message)
        out = self.outputs(sol.y)
        out["tau_in_cmd"] = np.array([tau(tt) for tt in t_s])
        out["dq_in"] = (out["tau_in_cmd"] - out["tau_in_cable"]) / self.P.b_in
        out["sol"] = sol
        return out


def uniform_params(N, theta, T_in, T_out=None, T_in_lower=None, T_out_lower=None, **kw):
    mu = kw.get("mu", 0.052)
    T_out = T_in if T_out is None else T_out
    T_in_lower = T_in if T_in_lower is None else T_in_lower
    T_out_lower = T_out if T_out_lower is None else T_out_lower
    th = np.full(N, theta / N)
    return Params(th, th.copy(), pretension_field(th, T_in, T_out, mu),
                  pretension_field(th, T_in_lower, T_out_lower, mu), **kw)
