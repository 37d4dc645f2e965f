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
gravity (``J ddq + B dq = tau_out + tau_grav(q) + tau_ext``, see :mod:`models.link`).

The initial state is the given pretension field with all nodes at rest. A segment
tension reaching zero (slack) leaves the model's range: :class:`OperatingRangeError`.
After any error the state is undefined until :meth:`DistributedModel.reset`.

Numerics: :mod:`models.distributed_rhs` (right-hand side, Jacobian) and
:mod:`models.distributed_integrator` (L-stable SDIRK2, O(N) Newton solves),
:mod:`models.distributed_dense` (offline error-controlled runs across sample times).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
from numba import njit

from models import distributed_dense as dense
from models import distributed_integrator as di
from models import distributed_rhs as rhs
from models.errors import ConfigError, IntegrationError, OperatingRangeError
from models.link import LinkParams


class InputMode(IntEnum):
    """How the input pulley is driven."""

    TORQUE = 0   #: commanded cable torque, ``b_in dq_in = tau_in - tau_in,cable``
    MOTOR = 1    #: motor inertia, ``J_m ddq_in + B_m dq_in = tau_m - tau_in,cable``


class OutputMode(IntEnum):
    """What the output pulley drives."""

    TESTBED = 0  #: passive environment ``J_out ddq + b_out dq + k_out q = tau_out``
    LINK = 1     #: link with gravity ``J ddq + B dq = tau_out + tau_grav(q) + tau_ext``


def _vec(name: str, value: object, length: int | None, positive: bool) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 1:
        raise ConfigError(name, f"must be a 1-D array, got shape {arr.shape}")
    if length is not None and arr.shape[0] != length:
        raise ConfigError(name, f"must have length {length}, got {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(name, "must be finite")
    if positive and np.any(arr <= 0.0):
        raise ConfigError(name, f"must be > 0, got min {arr.min()}")
    if not positive and np.any(arr < 0.0):
        raise ConfigError(name, f"must be >= 0, got min {arr.min()}")
    return arr


def _pos(name: str, x: float, strict: bool = True) -> None:
    if not math.isfinite(x) or (x <= 0.0 if strict else x < 0.0):
        raise ConfigError(name, f"must be {'>' if strict else '>='} 0 and finite, got {x}")


@dataclass(frozen=True)
class TransmissionParams:
    """Transmission geometry, pretension field and material.

    :ivar theta_upper_rad: (N,) accumulated bending angle of each internal node's
        segment, routing order input -> output.
    :ivar theta_lower_rad: (N,) same for the lower cable, routing order input -> output.
    :ivar tension_upper_N: (N+1,) initial segment tensions, routing order input -> output.
    :ivar tension_lower_N: (N+1,) initial segment tensions, routing order input -> output.
    :ivar stiffness_Nm_rad: K_c, static torsional stiffness with mu = 0 [Nm/rad].
    :ivar mu: friction coefficient [-]. :ivar p: smoothness exponent of eq (13).
    :ivar r_in_m, r_out_m: pulley radii [m]. :ivar b_node_Ns_m: damping of each internal
        node [N s/m], the paper's b_l = 1e-3 N s/mm (Table 3), per node, not per cable. It
        is not negligible: with the smooth law (13) a node creeps at ``g / b`` below the
        Coulomb limit, and a sliding cable drags ``N b v``. On the testbed multisine
        (theta = 3 rad, T0 = 150 N) tau_out moves by 0.04-0.08 Nm RMSE for b = 0.1 and by
        0.14-0.6 Nm for b = 10 (N = 10-50); an implementation must use the same value.
    :raises ConfigError: on wrong shapes or non-positive / non-finite values.
    """

    theta_upper_rad: np.ndarray
    theta_lower_rad: np.ndarray
    tension_upper_N: np.ndarray
    tension_lower_N: np.ndarray
    stiffness_Nm_rad: float = 240.0
    mu: float = 0.052
    p: float = 100.0
    r_in_m: float = 0.04
    r_out_m: float = 0.04
    b_node_Ns_m: float = 1.0

    def __post_init__(self) -> None:
        tu = _vec("transmission.theta_upper_rad", self.theta_upper_rad, None, False)
        n = tu.shape[0]
        if n < 1:
            raise ConfigError("transmission.theta_upper_rad", "needs at least one node (N >= 1)")
        object.__setattr__(self, "theta_upper_rad", tu)
        object.__setattr__(self, "theta_lower_rad",
                           _vec("transmission.theta_lower_rad", self.theta_lower_rad, n, False))
        object.__setattr__(self, "tension_upper_N",
                           _vec("transmission.tension_upper_N", self.tension_upper_N, n + 1, True))
        object.__setattr__(self, "tension_lower_N",
                           _vec("transmission.tension_lower_N", self.tension_lower_N, n + 1, True))
        _pos("transmission.stiffness_Nm_rad", self.stiffness_Nm_rad)
        _pos("transmission.mu", self.mu, strict=False)
        _pos("transmission.p", self.p)
        _pos("transmission.r_in_m", self.r_in_m)
        _pos("transmission.r_out_m", self.r_out_m)
        _pos("transmission.b_node_Ns_m", self.b_node_Ns_m)

    @property
    def n_nodes(self) -> int:
        """Number of internal nodes per cable N."""
        return int(self.theta_upper_rad.shape[0])

    @property
    def cable_stiffness_N_m(self) -> float:
        """Axial stiffness of one whole cable ``K_c / (2 r_in r_out)`` [N/m]."""
        return self.stiffness_Nm_rad / (2.0 * self.r_in_m * self.r_out_m)

    @property
    def segment_stiffness_N_m(self) -> float:
        """Stiffness of one of the N+1 segments ``(N+1) K_c / (2 r_in r_out)`` [N/m]."""
        return (self.n_nodes + 1) * self.cable_stiffness_N_m

    @staticmethod
    def uniform(n_nodes: int, theta_rad: float, pretension_N: float, **kw: float) -> "TransmissionParams":
        """Uniform curvature (theta_i = theta/N) with the limiting capstan pretension
        field of eq (23): boundary pretension ``pretension_N`` at both fixtures, decaying by
        ``exp(-mu theta_i)`` per node from each end, the larger of the two profiles.

        :raises ConfigError: on invalid arguments.
        """
        if n_nodes < 1:
            raise ConfigError("transmission.n_nodes", f"must be >= 1, got {n_nodes}")
        mu = float(kw.get("mu", 0.052))
        th = np.full(n_nodes, theta_rad / n_nodes)
        cum = np.concatenate(([0.0], np.cumsum(th)))          # bending passed before seg j
        tens = pretension_N * np.maximum(np.exp(-mu * cum), np.exp(-mu * (cum[-1] - cum)))
        return TransmissionParams(th, th.copy(), tens, tens.copy(), **kw)


@dataclass(frozen=True)
class BoundaryParams:
    """Boundary conditions of the input and output pulleys.

    :ivar b_in_Nms_rad: TORQUE mode regularising damping [Nm s/rad]; default 1e-3 gives
        a time constant ``b_in / K_c`` of about 4 us, so q_in follows the torque well
        within a control period (torque lag ``b_in dq_in`` ~ 1 mNm at 1 rad/s).
    :ivar motor_inertia_kg_m2: J_m (MOTOR mode) [kg m^2] (design.md: 0.73).
    :ivar motor_damping_Nms_rad: B_m (MOTOR mode) [Nm s/rad]; default 0.1 is a
        placeholder for a lightly damped servo until identified (damping ratio ~0.004 on K_c).
    :ivar k_out_Nm_rad, b_out_Nms_rad, out_inertia_kg_m2: TESTBED environment; with zero
        inertia (default, massless as in the paper) ``b_out`` must be > 0.
    :ivar link: LINK mode parameters (:class:`models.link.LinkParams`).
    :raises ConfigError: on invalid values.
    """

    input_mode: InputMode = InputMode.TORQUE
    b_in_Nms_rad: float = 1e-3
    motor_inertia_kg_m2: float = 0.73
    motor_damping_Nms_rad: float = 0.1
    output_mode: OutputMode = OutputMode.TESTBED
    k_out_Nm_rad: float = 20.0
    b_out_Nms_rad: float = 2.0
    out_inertia_kg_m2: float = 0.0
    link: LinkParams = field(default_factory=LinkParams)

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "input_mode", InputMode(self.input_mode))
        except ValueError as exc:
            raise ConfigError("boundary.input_mode", f"unknown mode {self.input_mode!r}") from exc
        try:
            object.__setattr__(self, "output_mode", OutputMode(self.output_mode))
        except ValueError as exc:
            raise ConfigError("boundary.output_mode", f"unknown mode {self.output_mode!r}") from exc
        _pos("boundary.b_in_Nms_rad", self.b_in_Nms_rad, strict=self.input_mode == InputMode.TORQUE)
        _pos("boundary.motor_inertia_kg_m2", self.motor_inertia_kg_m2,
             strict=self.input_mode == InputMode.MOTOR)
        _pos("boundary.motor_damping_Nms_rad", self.motor_damping_Nms_rad, strict=False)
        _pos("boundary.k_out_Nm_rad", self.k_out_Nm_rad, strict=False)
        _pos("boundary.out_inertia_kg_m2", self.out_inertia_kg_m2, strict=False)
        massless = self.output_mode == OutputMode.TESTBED and self.out_inertia_kg_m2 == 0.0
        _pos("boundary.b_out_Nms_rad", self.b_out_Nms_rad, strict=massless)
        if self.output_mode == OutputMode.LINK:
            _pos("boundary.link.inertia_kg_m2", self.link.inertia_kg_m2)
            _pos("boundary.link.damping_Nms_rad", self.link.damping_Nms_rad, strict=False)


@dataclass
class SimResult:
    """Offline run sampled at the input times (row 0 = the state at ``t_s[0]``).

    Tension arrays are in routing order input -> output; fixture tensions are
    (upper input-side, upper output-side, lower output-side, lower input-side) [N].
    """

    t_s: np.ndarray
    q_in_rad: np.ndarray
    q_out_rad: np.ndarray
    dq_in_rad_s: np.ndarray
    dq_out_rad_s: np.ndarray
    tau_in_Nm: np.ndarray
    tau_out_Nm: np.ndarray
    fixture_tensions_N: np.ndarray
    tensions_upper_N: np.ndarray
    tensions_lower_N: np.ndarray
    n_steps: int = 0
    n_rhs: int = 0
    n_rejected: int = 0
    n_newton_failures: int = 0


@njit(cache=True)
def _node_coefficients(theta_r, mu_scale_r, b_node_r, mu, route, c_node, b_ring) -> int:
    """Per-ring-entry friction factor ``mu*scale*theta/2`` and damping from routing arrays.

    :returns: ``di.OK``, or ``di.ERR_PARAM`` if a damping is not > 0 or a friction
        multiplier not >= 0 (NaN included) or an array has the wrong length.
    """
    if mu_scale_r.shape[0] != theta_r.shape[0] or b_node_r.shape[0] != theta_r.shape[0]:
        return di.ERR_PARAM
    for j in range(route.shape[0]):
        r = route[j]
        if r < 0:
            c_node[j] = 0.0
            b_ring[j] = 1.0
        else:
            if not (b_node_r[r] > 0.0 and mu_scale_r[r] >= 0.0):
                return di.ERR_PARAM
            c_node[j] = 0.5 * mu * mu_scale_r[r] * theta_r[r]
            b_ring[j] = b_node_r[r]
    return di.OK


@njit(cache=True)
def _step_kernel(y, t0, t1, u, text, n, d0, theta_r, mu_scale_r, b_node_r, mu, route, c_node,
                 b_ring, bp, rtol, atol, adaptive, work, stats, info, obs, f_seg) -> int:
    st = _node_coefficients(theta_r, mu_scale_r, b_node_r, mu, route, c_node, b_ring)
    if st != di.OK:
        return st
    st = di.advance(y, t0, t1, u, u, text, text, n, d0, c_node, b_ring, bp, rtol, atol,
                    adaptive, work, stats, info)
    if st == di.OK:
        di.observe(y, u, n, d0, bp, f_seg, obs)
    return st


def input_series(t_s: np.ndarray, u_Nm: np.ndarray,
                 tau_ext_Nm: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validated contiguous float arrays (time [s], input torque [Nm], external torque [Nm],
    zero if ``None``) for a simulation run.

    :raises ConfigError: unless t_s is strictly increasing with >= 2 samples and both torque
        series have its shape and are finite.
    """
    t = np.ascontiguousarray(t_s, dtype=float)
    u = np.ascontiguousarray(u_Nm, dtype=float)
    if t.ndim != 1 or t.shape[0] < 2 or not np.all(np.diff(t) > 0):
        raise ConfigError("t_s", "must be a strictly increasing 1-D array of >= 2 samples")
    if u.shape != t.shape:
        raise ConfigError("u_Nm", f"must have the shape of t_s {t.shape}, got {u.shape}")
    te = np.zeros_like(t) if tau_ext_Nm is None else np.ascontiguousarray(tau_ext_Nm, dtype=float)
    if te.shape != t.shape:
        raise ConfigError("tau_ext_Nm", f"must have the shape of t_s {t.shape}, got {te.shape}")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(te))):
        raise ConfigError("u_Nm/tau_ext_Nm", "must be finite")
    return t, u, te


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
        m = 2 * n + 2
        self._m = m
        route = np.full(m, -1, dtype=np.int64)
        for j in range(1, n + 1):
            route[j] = j - 1
        for j in range(n + 2, m):
            route[j] = 3 * n + 1 - j
        self._route = route
        self._theta_r = np.concatenate((trans.theta_upper_rad, trans.theta_lower_rad))
        self._f0 = np.concatenate((trans.tension_upper_N, trans.tension_lower_N[::-1]))
        self.mu_scale = np.ones(2 * n)
        self.b_node_Ns_m = np.full(2 * n, trans.b_node_Ns_m)
        self._checked_arrays: tuple[object, object] = (None, None)
        self._c_node = np.zeros(m)
        self._b_ring = np.ones(m)
        self._cubic = 0.0
        bp = np.zeros(rhs.BP_SIZE)
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
        self._bp = bp
        self._y = np.zeros(m + 2)
        self._d0 = np.zeros(m)
        self._work = di.new_work(n)
        self._stats = np.zeros(di.N_STATS)
        self._info = np.zeros(3)
        self._obs = np.zeros(6)
        self._fseg = np.zeros(m)
        self._t = 0.0
        self._u = 0.0
        self.step_adaptive = False
        self.rtol = 1e-6
        self.atol = 1e-9
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Back to the initial pretension state (nodes at rest, q = 0), t = 0."""
        self._y[:] = 0.0
        self._d0[:] = self._elongation_for(self._f0)
        self._bp[rhs.BP_CC] = self._cubic * (self.n + 1) ** 2
        self._t = 0.0
        self._u = 0.0
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
        k = self.trans.segment_stiffness_N_m
        disp_now = self._elongation_for(self._fseg[segs]) - self._d0[segs]
        self._d0[segs] = self._elongation_for(target) - disp_now
        del k
        self._refresh_obs()

    def _refresh_obs(self) -> None:
        di.observe(self._y, self._u, self.n, self._d0, self._bp, self._fseg, self._obs)

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
        if not dt_s > 0.0:
            raise ConfigError("dt_s", f"must be > 0, got {dt_s}")
        if self.mu_scale is not self._checked_arrays[0] or self.b_node_Ns_m is not self._checked_arrays[1]:
            self._check_node_arrays()
        t1 = self._t + dt_s
        st = _step_kernel(self._y, self._t, t1, float(u_Nm), float(tau_ext_Nm), self.n, self._d0,
                          self._theta_r, self.mu_scale, self.b_node_Ns_m, self.trans.mu,
                          self._route, self._c_node, self._b_ring, self._bp, self.rtol, self.atol,
                          self.step_adaptive, self._work, self._stats, self._info, self._obs,
                          self._fseg)
        if st != di.OK:
            self._raise(st, t1)
        self._t = t1
        self._u = float(u_Nm)

    def simulate(self, t_s: np.ndarray, u_Nm: np.ndarray, tau_ext_Nm: np.ndarray | None = None,
                 adaptive: bool = True, rtol: float = 1e-6, atol: float = 1e-9,
                 record_tensions: bool = True) -> SimResult:
        """Offline run from the current state, starting at time ``t_s[0]``.

        Inputs are piecewise linear between the samples; outputs are sampled at ``t_s``.
        ``adaptive=True``: error-controlled steps chosen by the error estimate alone (they
        may span up to 8 sample intervals; outputs between step ends come from the
        step's stage-value interpolant, see :mod:`models.distributed_dense`), with the
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
        st = _run(self._y, t, u, te, self.n, self._d0, self._c_node, self._b_ring, self._bp,
                  float(rtol), float(atol), bool(adaptive), self._work, stats, self._info, obs,
                  seg, record_tensions)
        self._stats[di.S_ETA] = stats[di.S_ETA]
        self._stats[di.S_H] = stats[di.S_H]
        if st != di.OK:
            self._raise(st, float(t[-1]))
        self._t = float(t[-1])
        self._u = float(u[-1])
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
        return self._t

    @property
    def q_in_rad(self) -> float:
        """Input pulley angle [rad]."""
        return float(self._obs[0])

    @property
    def dq_in_rad_s(self) -> float:
        """Input pulley velocity [rad/s] (from the torque balance in TORQUE mode)."""
        return float(self._obs[1])

    @property
    def q_out_rad(self) -> float:
        """Output pulley angle [rad]."""
        return float(self._obs[2])

    @property
    def dq_out_rad_s(self) -> float:
        """Output pulley velocity [rad/s]."""
        return float(self._obs[3])

    @property
    def tau_in_Nm(self) -> float:
        """Cable torque at the input pulley ``r_in (f_01 - f_{2N+2,2N+3})`` [Nm]."""
        return float(self._obs[4])

    @property
    def tau_out_Nm(self) -> float:
        """Cable torque at the output pulley ``r_out (f_{N,N+1} - f_{N+2,N+3})`` [Nm]."""
        return float(self._obs[5])

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


@njit(cache=True)
def _run(y, t, u, te, n, d0, c_node, b_ring, bp, rtol, atol, adaptive, work, stats, info, obs,
         seg, record) -> int:
    if adaptive:
        return dense.run_dense(y, t, u, te, n, d0, c_node, b_ring, bp, rtol, atol, work, stats,
                               info, obs, seg, record)
    f_seg = work[di.W_FS][: 2 * n + 2]
    di.observe(y, u[0], n, d0, bp, f_seg, obs[0])
    seg[0, :] = f_seg
    for i in range(t.shape[0] - 1):
        st = di.advance(y, t[i], t[i + 1], u[i], u[i + 1], te[i], te[i + 1], n, d0, c_node,
                        b_ring, bp, rtol, atol, False, work, stats, info)
        if st != di.OK:
            return st
        di.observe(y, u[i + 1], n, d0, bp, f_seg, obs[i + 1])
        if record:
            seg[i + 1, :] = f_seg
    return di.OK
