"""The distributed model's equations as ``dy/dt = f(t, y)`` callables for general ODE
solvers (``scipy.integrate.solve_ivp``), built on the model's own compiled right-hand
side and analytic Jacobian, so that a foreign solver integrates *identical* equations.

The state ``y`` has the layout of :mod:`capstan.models.distributed.rhs` (``2N + 4`` entries; the
two velocity slots are constant zero for first-order pulleys). The input torque and the
external link torque are piecewise linear between their samples, as in
:meth:`capstan.models.distributed.model.DistributedModel.simulate`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from capstan.models.distributed import integrator as di
from capstan.models.distributed import rhs as rhs
from capstan.models.distributed.model import DistributedModel, _node_coefficients, input_series


@dataclass
class OdeProblem:
    """``dy/dt = fun(t, y)`` with Jacobian ``jac(t, y)`` of one model.

    :ivar y0: initial state (the model's current state) [SI, layout of ``distributed_rhs``].
    """

    model: DistributedModel
    t_s: np.ndarray
    u_Nm: np.ndarray
    tau_ext_Nm: np.ndarray
    y0: np.ndarray
    sparse_jac: bool = False

    def __post_init__(self) -> None:
        m = self.model
        nm = 2 * m.n + 2
        self._n = m.n
        self._m = nm
        self._M = np.zeros(nm + 2)
        rhs.mass_diag(m.n, m._b_ring, m._bp, self._M)
        self._F = np.zeros(nm + 2)
        self._fs = np.zeros(nm)
        self._kt = np.zeros(nm)
        self._jl = np.zeros(nm)
        self._jd = np.zeros(nm)
        self._ju = np.zeros(nm)
        self.n_fun = 0
        self.n_jac = 0

    def _inputs(self, t: float) -> tuple[float, float]:
        return (float(np.interp(t, self.t_s, self.u_Nm)), float(np.interp(t, self.t_s, self.tau_ext_Nm)))

    def _eval(self, t: float, y: np.ndarray) -> None:
        m = self.model
        u, te = self._inputs(t)
        rhs.eval_system(np.ascontiguousarray(y, dtype=float), u, te, self._n, m._d0, m._c_node,
                        m._b_ring, m._bp, self._fs, self._kt, self._F, self._jl, self._jd, self._ju)

    def fun(self, t: float, y: np.ndarray) -> np.ndarray:
        """``dy/dt`` at time ``t`` [s] and state ``y``."""
        self.n_fun += 1
        self._eval(t, y)
        return self._F / self._M

    def _pattern(self) -> None:
        """Index arrays of the Jacobian entries (built once)."""
        n, nm, bp = self._n, self._m, self.model._bp
        second = {0: bp[rhs.BP_IN_MODE] != 0.0,
                  n + 1: int(bp[rhs.BP_OUT_MODE]) != rhs.OUT_TESTBED_MASSLESS}
        vel = {0: nm, n + 1: nm + 1}
        damp = {0: bp[rhs.BP_B_M], n + 1: bp[rhs.BP_B_LINK]
                if int(bp[rhs.BP_OUT_MODE]) == rhs.OUT_LINK else bp[rhs.BP_B_OUT]}
        ring = np.arange(nm)
        row = ring.copy()
        const_r: list[int] = []
        const_c: list[int] = []
        const_v: list[float] = []
        for j in (0, n + 1):
            if second[j]:
                # q' = v ; v' = (torque balance - damping v) / inertia
                row[j] = vel[j]
                const_r += [j, vel[j]]
                const_c += [vel[j], vel[j]]
                const_v += [1.0, -damp[j] / self._M[vel[j]]]
        self._rows = np.concatenate((row, row, row, np.array(const_r, dtype=np.int64)))
        self._cols = np.concatenate(((ring - 1) % nm, ring, (ring + 1) % nm, np.array(const_c, dtype=np.int64)))
        self._const = np.array(const_v)
        self._scale = 1.0 / self._M[row]

    def jac(self, t: float, y: np.ndarray) -> np.ndarray | sp.csc_matrix:
        """Exact Jacobian ``d(dy/dt)/dy`` (the model's analytic ring Jacobian): a dense
        array, or scipy sparse CSC if the problem was built with ``sparse_jac=True``."""
        self.n_jac += 1
        self._eval(t, y)
        if not hasattr(self, "_rows"):
            self._pattern()
        s = self._scale
        vals = np.concatenate((self._jl * s, self._jd * s, self._ju * s, self._const))
        size = self._m + 2
        if self.sparse_jac:
            return sp.csc_matrix((vals, (self._rows, self._cols)), shape=(size, size))
        out = np.zeros((size, size))
        np.add.at(out, (self._rows, self._cols), vals)
        return out

    def tau_out_Nm(self, y_cols: np.ndarray, u_Nm: np.ndarray) -> np.ndarray:
        """Output torque [Nm] of each state column of ``y_cols`` ((2N+4, k))."""
        m = self.model
        out = np.zeros(6)
        fs = np.zeros(self._m)
        tau = np.empty(y_cols.shape[1])
        for k in range(y_cols.shape[1]):
            di.observe(np.ascontiguousarray(y_cols[:, k]), float(u_Nm[k]), self._n, m._d0, m._bp, fs, out)
            tau[k] = out[5]
        return tau


def ode_problem(model: DistributedModel, t_s: np.ndarray, u_Nm: np.ndarray,
                tau_ext_Nm: np.ndarray | None = None, sparse_jac: bool = False) -> OdeProblem:
    """The equations of ``model`` from its current state with piecewise-linear inputs.

    :param t_s: strictly increasing sample times [s]; :param u_Nm: input torque samples
        (tau_in in TORQUE mode, tau_m in MOTOR mode) [Nm]; :param tau_ext_Nm: external link
        torque samples [Nm] (default zero).
    :param sparse_jac: return the Jacobian as scipy sparse CSC (better for large N).
    :raises ConfigError: on malformed inputs or invalid node parameters.
    """
    t, u, te = input_series(t_s, u_Nm, tau_ext_Nm)
    model._check_node_params()
    _node_coefficients(model._theta_r, model.mu_scale, model.b_node_Ns_m, model.trans.mu,
                       model._route, model._c_node, model._b_ring)
    return OdeProblem(model, t, u, te, model._y.copy(), sparse_jac)
