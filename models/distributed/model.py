"""Distributed full-order model of the dual-cable tendon-sheath transmission.

Paper eqs (2)-(13) with the errata of design.md §2:

* two antagonistic cables, each ``N + 1`` serial springs with ``N`` massless internal
  nodes (eq 3: ``b_i dx_i/dt = f_{i-1,i} - f_{i,i+1} - f_fric,i``);
* smooth Coulomb friction (11)-(13) on the curvature-induced normal force
  ``f_N,i = (f_{i-1,i} + f_{i,i+1}) theta_i / 2``, exponent ``p`` (100);
* input torque (2) ``tau_in = r_in (f_{0,1} - f_{2N+2,2N+3})``, output torque as the
  *difference* ``tau_out = r_out (f_{N,N+1} - f_{N+2,N+3})`` (erratum of (4)/(6));
* pulley coupling (9) with the cable-end displacement ``r * q`` (arc length). The paper
  prints ``q / r``, which is dimensionally inconsistent and contradicts the stiffness
  identification; with ``r * q`` the configured stiffness is reproduced exactly.

Stiffness convention: segment stiffness ``k = (N + 1) K_c / (2 r_in r_out)``, i.e. each
cable has axial stiffness ``K_c / (2 r_in r_out)`` (75 kN/m for 240 Nm/rad, 40 mm). With
``mu = 0`` the static transmission then obeys ``tau_out = K_c (q_in - (r_out/r_in) q_out)``
and ``tau_in = (r_in / r_out) tau_out``: ``K_c`` is the torsional stiffness referred to the
input-side deflection seen at the output (for ``r_in = r_out`` simply
``tau = K_c (q_in - q_out)``).

Boundary conditions (:class:`InputMode`, :class:`OutputMode`): torque-driven input with a
small regularising damping (paper) or a motor inertia; output on the testbed
(``J_out ddq + b_out dq + k_out q = tau_out``, J_out = 0 by default) or the link with
gravity (``J ddq + B dq = tau_out + tau_grav(q) + tau_ext``, see :mod:`capstan.models.transmission.link`).

The initial state is the given pretension field with all nodes at rest. A segment
tension reaching zero (slack) leaves the model's range: :class:`OperatingRangeError`.
After any error the state is undefined until :meth:`DistributedModel.reset`.

Numerics: :mod:`capstan.models.distributed.rhs` (right-hand side, Jacobian) and
:mod:`capstan.models.distributed.integrator` (L-stable SDIRK2, O(N) Newton solves),
:mod:`capstan.models.distributed.dense` (offline error-controlled runs across sample times),
:mod:`capstan.models.distributed.kernels` (compiled entry points, the model's packed state buffer).
Parameters and the run result: :mod:`capstan.models.distributed.params` (re-exported here).
"""

from __future__ import annotations

import math

import numpy as np

from capstan.models.distributed import integrator as di
from capstan.models.distributed import kernels as kern
from capstan.models.distributed import rhs as rhs
from capstan.models.distributed.kernels import node_coefficients as _node_coefficients
from capstan.models.distributed.params import (BoundaryParams, InputMode, OutputMode, SimResult,
                                       TransmissionParams, input_series)
from capstan.models.common.errors import ConfigError, IntegrationError, OperatingRangeError

__all__ = ["BoundaryParams", "DistributedModel", "InputMode", "OutputMode", "SimResult",
           "TransmissionParams", "input_series"]


class DistributedModel:
    """The distributed transmission + pulley boundary dynamics, stepped or run offline.

    Mutable between steps (effect injection), all in routing order (index ``0..N-1`` the
    upper cable's nodes from input to output, ``N..2N-1`` the lower cable's nodes from
    input to output):

    * ``mu_scale`` (2N,) per-node friction multiplier (default 1);
    * ``b_node_Ns_m`` (2N,) per-node damping [N s/m] (must stay > 0);
    * ``stiffness_cubic_1_m2`` hardening ``f = k_c D (1 + c D^2)`` on the cable-equivalent
      elongation ``D = (N+1) d`` of each segment (``d`` = segment elongation from its slack
      length, ``k_c`` the cable stiffness); slack lengths are fixed at :meth:`reset` so the
      initial tensions are met; changing ``c`` later changes tensions at fixed geometry;
    * :meth:`shift_pretension`;
    * ``step_adaptive``, ``rtol``, ``atol``: integrator settings of :meth:`step`.

    :raises ConfigError: on invalid parameters.
    """

    def __init__(self, trans: TransmissionParams, bnd: BoundaryParams) -> None:
        self.trans = trans
        self.bnd = bnd
        n = trans.n_nodes
        self.n = n
        self._m = 2 * n + 2
        # all per-step arrays and settings live in one packed buffer (models.distributed_kernels)
        self._fb, self._ib = kern.new_buffers(n)
        self._bind_views()
        self._theta_r[:] = np.concatenate((trans.theta_upper_rad, trans.theta_lower_rad))
        self._f0 = np.concatenate((trans.tension_upper_N, trans.tension_lower_N[::-1]))
        self._own_mu_scale[:] = 1.0
        self._own_b_node[:] = trans.b_node_Ns_m
        self.mu_scale = self._own_mu_scale
        self.b_node_Ns_m = self._own_b_node
        self._checked_arrays: tuple[object, object] = (None, None)
        self._b_ring[:] = 1.0
        self._cubic = 0.0
        bp = self._bp
        bp[rhs.BP_IN_MODE] = float(int(bnd.input_mode))
        bp[rhs.BP_B_IN] = bnd.b_in_Nms_rad
        bp[rhs.BP_J_M] = bnd.motor_inertia_kg_m2
        bp[rhs.BP_B_M] = bnd.motor_damping_Nms_rad
        if bnd.output_mode == OutputMode.LINK:
            bp[rhs.BP_OUT_MODE] = rhs.OUT_LINK
            bp[rhs.BP_J_OUT] = bnd.link.inertia_kg_m2
            bp[rhs.BP_B_LINK] = bnd.link.damping_Nms_rad
            bp[rhs.BP_MGL] = bnd.link.m_g_l_Nm
        else:
            massless = bnd.out_inertia_kg_m2 == 0.0
            bp[rhs.BP_OUT_MODE] = rhs.OUT_TESTBED_MASSLESS if massless else rhs.OUT_TESTBED_INERTIA
            bp[rhs.BP_J_OUT] = bnd.out_inertia_kg_m2
        bp[rhs.BP_K_OUT] = bnd.k_out_Nm_rad
        bp[rhs.BP_B_OUT] = bnd.b_out_Nms_rad
        bp[rhs.BP_R_IN] = trans.r_in_m
        bp[rhs.BP_R_OUT] = trans.r_out_m
        bp[rhs.BP_K_SEG] = trans.segment_stiffness_N_m
        bp[rhs.BP_MU] = trans.mu
        bp[rhs.BP_P] = trans.p
        self.step_adaptive = False
        self.rtol = 1e-6
        self.atol = 1e-9
        self.reset()

    # attributes that are views of the packed buffer ``_fb`` (slot in models.distributed_kernels)
    _VIEWS = (("_y", kern.O_Y), ("_d0", kern.O_D0), ("_theta_r", kern.O_THETA),
              ("_own_mu_scale", kern.O_MU_SCALE), ("_own_b_node", kern.O_B_NODE),
              ("_c_node", kern.O_C_NODE), ("_b_ring", kern.O_B_RING), ("_bp", kern.O_BP),
              ("_stats", kern.O_STATS), ("_info", kern.O_INFO), ("_obs", kern.O_OBS),
              ("_fseg", kern.O_FSEG), ("_work", kern.O_WORK))
    _UNCOPIED = frozenset(name for name, _ in _VIEWS) | {"_route", "_step_held", "_checked_arrays"}

    def _bind_views(self) -> None:
        """(Re)create the attributes that are views of the packed buffers ``_fb``/``_ib``."""
        for name, slot in self._VIEWS:
            setattr(self, name, kern.view(self._fb, self._ib, slot))
        self._route = self._ib[kern.I_ROUTE:]
        self._step_held = self._first_step_held

    def __getstate__(self) -> dict[str, object]:
        """State for copy/pickle: the buffers without their views (a copied view would no
        longer alias the copied buffer); ``mu_scale`` / ``b_node_Ns_m`` only if replaced."""
        state = {k: v for k, v in self.__dict__.items() if k not in self._UNCOPIED}
        if self.mu_scale is self._own_mu_scale:
            state["mu_scale"] = None
        if self.b_node_Ns_m is self._own_b_node:
            state["b_node_Ns_m"] = None
        return state

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state)
        self._bind_views()
        self._checked_arrays = (None, None)
        if self.mu_scale is None:
            self.mu_scale = self._own_mu_scale
        if self.b_node_Ns_m is None:
            self.b_node_Ns_m = self._own_b_node

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Back to the initial pretension state (nodes at rest, q = 0), t = 0."""
        self._y[:] = 0.0
        self._d0[:] = self._elongation_for(self._f0)
        self._bp[rhs.BP_CC] = self._cubic * (self.n + 1) ** 2
        self._fb[kern.F_T] = 0.0
        self._fb[kern.F_U] = 0.0
        self._stats[:] = 0.0
        self._work[di.W_KP, :] = 0.0
        self._work[di.W_P1, :] = 0.0
        self._work[di.W_P2, :] = 0.0
        self._work[di.W_HP, :] = 0.0
        di.observe(self._y, 0.0, self.n, self._d0, self._bp, self._fseg, self._obs)

    def _elongation_for(self, f_N: np.ndarray) -> np.ndarray:
        """Segment elongations [m] giving tensions ``f_N`` with the current spring law."""
        k = self.trans.segment_stiffness_N_m
        d = np.asarray(f_N, dtype=float) / k
        cc = self._cubic * (self.n + 1) ** 2
        for _ in range(50):
            if cc == 0.0:
                break
            res = k * d * (1.0 + cc * d * d) - f_N
            d = d - res / (k * (1.0 + 3.0 * cc * d * d))
            if np.max(np.abs(res)) < 1e-12 * max(1.0, float(np.max(np.abs(f_N)))):
                break
        return d

    @property
    def step_adaptive(self) -> bool:
        """:meth:`step` error-controlled (True) or one step per call, split only on Newton
        failure (False, default)."""
        return self._fb.item(kern.F_ADAPT) != 0.0

    @step_adaptive.setter
    def step_adaptive(self, on: bool) -> None:
        self._fb[kern.F_ADAPT] = 1.0 if on else 0.0

    @property
    def rtol(self) -> float:
        """Relative tolerance of :meth:`step` (Newton; error control if adaptive) [-]."""
        return self._fb.item(kern.F_RTOL)

    @rtol.setter
    def rtol(self, value: float) -> None:
        self._fb[kern.F_RTOL] = value

    @property
    def atol(self) -> float:
        """Absolute tolerance of :meth:`step` [m, rad] (x 1e3 for velocity states)."""
        return self._fb.item(kern.F_ATOL)

    @atol.setter
    def atol(self, value: float) -> None:
        self._fb[kern.F_ATOL] = value

    @property
    def stiffness_cubic_1_m2(self) -> float:
        """Cubic hardening coefficient on cable-equivalent elongation [1/m^2] (0 = linear)."""
        return self._cubic

    @stiffness_cubic_1_m2.setter
    def stiffness_cubic_1_m2(self, c: float) -> None:
        if not math.isfinite(c) or c < 0.0:
            raise ConfigError("stiffness_cubic_1_m2", f"must be >= 0 and finite, got {c}")
        self._cubic = float(c)
        self._bp[rhs.BP_CC] = self._cubic * (self.n + 1) ** 2
        self._refresh_obs()

    def shift_pretension(self, delta_N: float, at_fixtures: bool = False) -> None:
        """Change the pretension of both cables by ``delta_N`` [N] at the current state.

        Default: every segment's slack length changes so that every segment tension moves
        by ``delta_N`` (distributed relaxation/creep; nodes stay in equilibrium). With
        ``at_fixtures=True`` only the four fixture offsets move (screw adjustment): the end
        segments change by ``delta_N`` and friction governs how it spreads.

        :raises OperatingRangeError: if a segment would become slack.
        """
        segs = np.arange(self._m) if not at_fixtures else np.array([0, self.n, self.n + 1, self._m - 1])
        target = self._fseg[segs] + delta_N
        if np.any(target <= 0.0):
            raise OperatingRangeError(f"shift_pretension({delta_N} N) would make a segment slack "
                                      f"(min tension {target.min():.3f} N)")
        disp_now = self._elongation_for(self._fseg[segs]) - self._d0[segs]
        self._d0[segs] = self._elongation_for(target) - disp_now
        self._refresh_obs()

    def _refresh_obs(self) -> None:
        di.observe(self._y, self._fb.item(kern.F_U), self.n, self._d0, self._bp, self._fseg,
                   self._obs)

    # ------------------------------------------------------------ stepping
    def _check_node_arrays(self) -> None:
        """Shape/dtype check of ``mu_scale`` and ``b_node_Ns_m``, redone only when one of
        them was replaced (their values are checked on every step by the kernel)."""
        ms, bn = self.mu_scale, self.b_node_Ns_m
        if ms is self._checked_arrays[0] and bn is self._checked_arrays[1]:
            return
        for name, arr in (("mu_scale", ms), ("b_node_Ns_m", bn)):
            if not isinstance(arr, np.ndarray) or arr.shape != (2 * self.n,) or arr.dtype != np.float64:
                raise ConfigError(name, f"must be a float64 array of shape ({2 * self.n},)")
        self._checked_arrays = (ms, bn)

    def _check_node_params(self) -> None:
        self._check_node_arrays()
        if not (np.all(self.b_node_Ns_m > 0.0) and np.all(self.mu_scale >= 0.0)):
            raise ConfigError("b_node_Ns_m/mu_scale", "b_node must be > 0, mu_scale >= 0")

    def _raise(self, status: int, t_hint: float) -> None:
        if status == di.ERR_PARAM:
            self._check_node_params()
            raise ConfigError("b_node_Ns_m/mu_scale", "b_node must be > 0, mu_scale >= 0")
        t = self._info[di.I_T]
        if status == di.ERR_SLACK:
            j = int(self._info[di.I_SEG])
            cable, seg = ("upper", j) if j <= self.n else ("lower", 2 * self.n + 1 - j)
            raise OperatingRangeError(
                f"cable slack at t = {t:.6f} s: {cable} cable segment {seg} (routing order, "
                f"0 = input side) tension {self._info[di.I_TENSION]:.3f} N <= 0; the model "
                "assumes pretensioned cables without slack")
        if status == di.ERR_NONFINITE:
            raise IntegrationError(f"non-finite state at t = {t:.6f} s")
        raise IntegrationError(f"Newton iteration did not converge at t = {t:.6f} s "
                               f"(step size underflow, interval ending {t_hint:.6f} s)")

    def step(self, dt_s: float, u_Nm: float, tau_ext_Nm: float = 0.0) -> None:
        """Advance by ``dt_s`` with the input torque held (tau_in in TORQUE mode, tau_m in
        MOTOR mode) and the external link torque ``tau_ext_Nm`` held.

        One L-stable SDIRK2 step per call, split only if Newton needs it (or error
        controlled with ``step_adaptive = True``).

        :raises ConfigError: if ``dt_s`` is not > 0 or the node parameters are invalid.
        :raises OperatingRangeError: if a cable goes slack.
        :raises IntegrationError: if the integrator fails.
        """
        # hot path (once per control period): one compiled call on the packed buffers
        if self.mu_scale is self._own_mu_scale and self.b_node_Ns_m is self._own_b_node:
            st = self._step_held(self._fb, self._ib, dt_s, u_Nm, tau_ext_Nm)
        else:
            st = self._step_replaced(dt_s, u_Nm, tau_ext_Nm)
        if st:
            self._step_failed(st, dt_s)

    def _first_step_held(self, fb: np.ndarray, ib: np.ndarray, dt_s: float, u_Nm: float,
                         tau_ext_Nm: float) -> int:
        """First fast-path :meth:`step`: binds the compiled kernel (loaded or compiled only
        now, so models that only :meth:`simulate` do not pay for it), then steps."""
        self._step_held = kern.step_held_entry()
        return self._step_held(fb, ib, dt_s, u_Nm, tau_ext_Nm)

    def _step_replaced(self, dt_s: float, u_Nm: float, tau_ext_Nm: float) -> int:
        """:meth:`step` with ``mu_scale`` or ``b_node_Ns_m`` replaced by arrays other than the
        model's own (passed to the kernel as they are, so later in-place changes count).

        :returns: the kernel's status code (``kern.ERR_DT`` for a ``dt_s`` not > 0).
        """
        self._check_node_arrays()
        return kern.step_held_with(self._fb, self._ib, float(dt_s), float(u_Nm), float(tau_ext_Nm),
                                   self.mu_scale, self.b_node_Ns_m)

    def _step_failed(self, status: int, dt_s: float) -> None:
        """Raise the exception of a failed :meth:`step` (``status`` from the kernel)."""
        if status == kern.ERR_DT:
            raise ConfigError("dt_s", f"must be > 0, got {dt_s}")
        self._raise(status, self._fb.item(kern.F_T) + float(dt_s))

    def simulate(self, t_s: np.ndarray, u_Nm: np.ndarray, tau_ext_Nm: np.ndarray | None = None,
                 adaptive: bool = True, rtol: float = 1e-6, atol: float = 1e-9,
                 record_tensions: bool = True) -> SimResult:
        """Offline run from the current state, starting at time ``t_s[0]``.

        Inputs are piecewise linear between the samples; outputs are sampled at ``t_s``.
        ``adaptive=True``: error-controlled steps chosen by the error estimate alone (they
        may span up to 8 sample intervals; outputs between step ends come from the
        step's stage-value interpolant, see :mod:`capstan.models.distributed.dense`), with the
        weighted RMS tolerance ``atol + rtol |y|`` (``atol`` in m and rad); else one step
        per sample interval (split only on Newton failure). ``rtol``/``atol`` also set the
        Newton tolerance in fixed mode. The model is left at the final state.

        :raises ConfigError: on malformed inputs.
        :raises OperatingRangeError: on cable slack. :raises IntegrationError: on failure.
        """
        t, u, te = input_series(t_s, u_Nm, tau_ext_Nm)
        self._check_node_params()
        _node_coefficients(self._theta_r, self.mu_scale, self.b_node_Ns_m, self.trans.mu,
                           self._route, self._c_node, self._b_ring)
        ns = t.shape[0]
        obs = np.zeros((ns, 6))
        seg = np.zeros((ns if record_tensions else 1, self._m))
        stats = np.zeros(di.N_STATS)
        # the run continues the integrator state of step() (Newton contraction estimate,
        # step-size proposal) like one more step() would
        stats[di.S_ETA] = self._stats[di.S_ETA]
        stats[di.S_H] = self._stats[di.S_H]
        st = kern.run(self._y, t, u, te, self.n, self._d0, self._c_node, self._b_ring, self._bp,
                  float(rtol), float(atol), bool(adaptive), self._work, stats, self._info, obs,
                  seg, record_tensions)
        self._stats[di.S_ETA] = stats[di.S_ETA]
        self._stats[di.S_H] = stats[di.S_H]
        if st != di.OK:
            self._raise(st, float(t[-1]))
        self._fb[kern.F_T] = t[-1]
        self._fb[kern.F_U] = u[-1]
        self._refresh_obs()
        if record_tensions:
            up = seg[:, : self.n + 1].copy()
            lo = seg[:, self.n + 1:][:, ::-1].copy()
            fix = np.stack((up[:, 0], up[:, -1], lo[:, -1], lo[:, 0]), axis=1)
        else:
            up = lo = np.zeros((0, self.n + 1))
            fix = np.zeros((0, 4))
        return SimResult(t, obs[:, 0], obs[:, 2], obs[:, 1], obs[:, 3], obs[:, 4], obs[:, 5],
                         fix, up, lo, int(stats[di.S_STEPS]), int(stats[di.S_RHS]),
                         int(stats[di.S_REJECT]), int(stats[di.S_NEWTON_FAIL]))

    # --------------------------------------------------------- observations
    @property
    def t_s(self) -> float:
        """Model time [s]."""
        return self._fb.item(kern.F_T)

    @property
    def q_in_rad(self) -> float:
        """Input pulley angle [rad]."""
        return self._obs.item(0)

    @property
    def dq_in_rad_s(self) -> float:
        """Input pulley velocity [rad/s] (from the torque balance in TORQUE mode)."""
        return self._obs.item(1)

    @property
    def q_out_rad(self) -> float:
        """Output pulley angle [rad]."""
        return self._obs.item(2)

    @property
    def dq_out_rad_s(self) -> float:
        """Output pulley velocity [rad/s]."""
        return self._obs.item(3)

    @property
    def tau_in_Nm(self) -> float:
        """Cable torque at the input pulley ``r_in (f_01 - f_{2N+2,2N+3})`` [Nm]."""
        return self._obs.item(4)

    @property
    def tau_out_Nm(self) -> float:
        """Cable torque at the output pulley ``r_out (f_{N,N+1} - f_{N+2,N+3})`` [Nm]."""
        return self._obs.item(5)

    @property
    def tensions_upper_N(self) -> np.ndarray:
        """(N+1,) upper-cable segment tensions, routing order input -> output [N]."""
        return self._fseg[: self.n + 1].copy()

    @property
    def tensions_lower_N(self) -> np.ndarray:
        """(N+1,) lower-cable segment tensions, routing order input -> output [N]."""
        return self._fseg[self.n + 1:][::-1].copy()

    @property
    def fixture_tensions_N(self) -> tuple[float, float, float, float]:
        """(upper input-side f_01, upper output-side f_{N,N+1}, lower output-side
        f_{N+2,N+3}, lower input-side f_{2N+2,2N+3}) [N]."""
        f = self._fseg
        return float(f[0]), float(f[self.n]), float(f[self.n + 1]), float(f[self._m - 1])

    @property
    def displacements_upper_m(self) -> np.ndarray:
        """(N+2,) upper-cable node displacements from the initial state incl. both ends
        (``r_in q_in``, x_1..x_N, ``r_out q_out``), routing order input -> output [m]."""
        y = self._y
        return np.concatenate(([self.trans.r_in_m * y[0]], y[1: self.n + 1],
                               [self.trans.r_out_m * y[self.n + 1]]))

    @property
    def displacements_lower_m(self) -> np.ndarray:
        """(N+2,) lower-cable node displacements incl. both ends, routing order
        input -> output (``r_in q_in``, x_{2N+2}..x_{N+3}, ``r_out q_out``) [m]."""
        y = self._y
        return np.concatenate(([self.trans.r_in_m * y[0]], y[self.n + 2: self._m][::-1],
                               [self.trans.r_out_m * y[self.n + 1]]))

    @property
    def stats(self) -> dict[str, int]:
        """Integrator counters of :meth:`step` since :meth:`reset`."""
        s = self._stats
        return {"n_steps": int(s[di.S_STEPS]), "n_rhs": int(s[di.S_RHS]),
                "n_rejected": int(s[di.S_REJECT]), "n_newton_failures": int(s[di.S_NEWTON_FAIL])}
