"""Reduced analytical transmission model (paper eqs 14-21) in torsional-unit form.

**Nominal friction torque (eq 19).** For N = 1 each cable has two springs; eq (19) reads
``tau_fc = (mu theta / 2)(f01 + f12 + f34 + f45) r_out``. At rest each cable's two spring
tensions sum to that cable's equivalent pretension (eq 25 is a per-cable *sum* of two
branch tensions, ``T0_eq = 2 T(s_min)``), i.e. ``f01 + f12 = f34 + f45 = T0_eq``, so::

    tau_fc = (mu theta / 2)(2 T0_eq) r_out = mu theta T0_eq r_out,

which is the second line of eq (19) with ``k (x0(0) - x2(0)) = f01 + f12 = T0_eq``.
(Uniform curvature, symmetric T0: ``tau_fc = 2 mu theta T0 exp(-mu theta / 2) r_out``.)

**Friction law (eq 21)**, exactly as printed::

    tau_hat(dq) = tanh(alpha dq) [zeta_c + (zeta_s - zeta_c) exp(-|dq / eta_s|^2)] tau_fc + b_vis dq

**Torsional unit (eq 20)**, first order in the virtual transmission angle q::

    gamma dq = rho tau_in - tau_out - tau_hat(dq),   tau_out = k_out q + b_out dq  (testbed, eq 22)

with ``rho = r_out / r_in`` (eq 16; 1 on the reference rig). When gamma is small the
velocity is an (almost) algebraic function of the torque balance, so the equation is
stiff: each step is backward Euler, solving the scalar implicit equation for the new
velocity with a bracketed (safeguarded) Newton iteration started at the previous
velocity. With zeta_s > zeta_c the equation can have several roots (the Stribeck dip);
starting from the previous velocity keeps the branch the motion is on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from capstan.models.common.config_tools import get_float, reject_unknown, section
from capstan.models.common.errors import IntegrationError, ModelError


def nominal_friction_torque_Nm(T0_eq_N: float, mu: float, theta_rad: float, r_out_m: float) -> float:
    """Nominal reduced-model friction torque ``tau_fc = mu theta T0_eq r_out`` [Nm] (eq 19).

    :param T0_eq_N: averaged (equivalent) pretension of eq 25 [N] (per-cable sum, see module doc).
    :param mu: sheath friction coefficient [-].
    :param theta_rad: total bending angle of the routing [rad].
    :param r_out_m: output pulley radius [m].
    :raises ModelError: on negative or non-finite arguments.
    """
    for name, v in (("T0_eq_N", T0_eq_N), ("mu", mu), ("theta_rad", theta_rad), ("r_out_m", r_out_m)):
        if not (math.isfinite(v) and v >= 0.0):
            raise ModelError(f"{name} must be finite and >= 0, got {v}")
    return float(mu) * float(theta_rad) * float(T0_eq_N) * float(r_out_m)


def eq19_friction_torque_Nm(f01_N: float, f12_N: float, f34_N: float, f45_N: float,
                            mu: float, theta_rad: float, r_out_m: float) -> float:
    """Eq (19), first line: ``(mu theta / 2)(f01 + f12 + f34 + f45) r_out`` [Nm] from N = 1 spring tensions [N]."""
    return 0.5 * mu * theta_rad * (f01_N + f12_N + f34_N + f45_N) * r_out_m


@njit(cache=True)
def stribeck_friction_Nm(dq_rad_s: float, tau_fc_Nm: float, zeta_s: float, zeta_c: float,
                         eta_s_rad_s: float, alpha_s_rad: float, b_vis_Nms_rad: float) -> float:
    """Stribeck-Coulomb-viscous friction torque of eq (21) [Nm].

    ``tanh(alpha dq) [zeta_c + (zeta_s - zeta_c) exp(-(dq/eta_s)^2)] tau_fc + b_vis dq``.

    :param dq_rad_s: velocity [rad/s] (transmission state, or the measured dq_out in the feedforward).
    :param tau_fc_Nm: nominal friction torque of eq 19 [Nm].
    :param zeta_s: static (stiction) scale [-], >= zeta_c.
    :param zeta_c: Coulomb scale [-] (paper: 1).
    :param eta_s_rad_s: Stribeck velocity [rad/s], > 0.
    :param alpha_s_rad: tanh steepness alpha [s/rad].
    :param b_vis_Nms_rad: viscous coefficient [Nm s/rad].
    """
    x = dq_rad_s / eta_s_rad_s
    return (math.tanh(alpha_s_rad * dq_rad_s) * (zeta_c + (zeta_s - zeta_c) * math.exp(-x * x)) * tau_fc_Nm
            + b_vis_Nms_rad * dq_rad_s)


@njit(cache=True)
def stribeck_friction_slope(dq_rad_s: float, tau_fc_Nm: float, zeta_s: float, zeta_c: float,
                            eta_s_rad_s: float, alpha_s_rad: float, b_vis_Nms_rad: float) -> float:
    """d tau_hat / d dq of eq (21) [Nm s/rad]."""
    x = dq_rad_s / eta_s_rad_s
    e = math.exp(-x * x)
    th = math.tanh(alpha_s_rad * dq_rad_s)
    phi = zeta_c + (zeta_s - zeta_c) * e
    dphi = (zeta_s - zeta_c) * e * (-2.0 * x / eta_s_rad_s)
    return tau_fc_Nm * (alpha_s_rad * (1.0 - th * th) * phi + th * dphi) + b_vis_Nms_rad


@dataclass(frozen=True)
class StribeckParams:
    """Shape parameters of eq (21) (the magnitude tau_fc comes from eq 19).

    Defaults are plausible values for the reference rig (not identified): a 30 % stiction
    peak decaying over ~0.05 rad/s, a tanh that is 96 % saturated at 0.01 rad/s, no extra
    viscous term. Identify them from data for real use.

    :ivar zeta_s: static scale [-], >= zeta_c.
    :ivar zeta_c: Coulomb scale [-] (paper fixes 1).
    :ivar eta_s_rad_s: Stribeck velocity [rad/s], > 0.
    :ivar alpha_s_rad: tanh steepness alpha [s/rad], > 0.
    :ivar b_vis_Nms_rad: extra viscous damping [Nm s/rad], >= 0.
    """

    zeta_s: float = 1.3
    zeta_c: float = 1.0
    eta_s_rad_s: float = 0.05
    alpha_s_rad: float = 200.0
    b_vis_Nms_rad: float = 0.0

    def __post_init__(self) -> None:
        if not (self.zeta_c >= 0.0 and self.zeta_s >= self.zeta_c):
            raise ModelError(f"need zeta_s >= zeta_c >= 0, got zeta_s={self.zeta_s}, zeta_c={self.zeta_c}")
        if not (self.eta_s_rad_s > 0.0 and self.alpha_s_rad > 0.0 and self.b_vis_Nms_rad >= 0.0):
            raise ModelError("need eta_s_rad_s > 0, alpha_s_rad > 0, b_vis_Nms_rad >= 0, got "
                             f"{self.eta_s_rad_s}, {self.alpha_s_rad}, {self.b_vis_Nms_rad}")

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], prefix: str = "stribeck") -> "StribeckParams":
        """Build from ``{zeta_s, zeta_c, eta_s_rad_s, alpha_s_rad, b_vis_Nms_rad}`` (all optional).

        :raises ConfigError: on unknown keys or invalid values (naming the key).
        """
        reject_unknown(cfg, {"zeta_s", "zeta_c", "eta_s_rad_s", "alpha_s_rad", "b_vis_Nms_rad"}, prefix)
        d = StribeckParams()
        zc = get_float(cfg, "zeta_c", prefix, d.zeta_c, min_value=0.0)
        zs = get_float(cfg, "zeta_s", prefix, max(d.zeta_s, zc), min_value=zc)
        return StribeckParams(
            zeta_s=zs, zeta_c=zc,
            eta_s_rad_s=get_float(cfg, "eta_s_rad_s", prefix, d.eta_s_rad_s, min_value=0.0, min_exclusive=True),
            alpha_s_rad=get_float(cfg, "alpha_s_rad", prefix, d.alpha_s_rad, min_value=0.0, min_exclusive=True),
            b_vis_Nms_rad=get_float(cfg, "b_vis_Nms_rad", prefix, d.b_vis_Nms_rad, min_value=0.0),
        )

    def friction_Nm(self, dq_rad_s: float, tau_fc_Nm: float) -> float:
        """Eq (21) at one velocity [Nm] (Python convenience around :func:`stribeck_friction_Nm`)."""
        return stribeck_friction_Nm(float(dq_rad_s), float(tau_fc_Nm), self.zeta_s, self.zeta_c,
                                    self.eta_s_rad_s, self.alpha_s_rad, self.b_vis_Nms_rad)


@njit(cache=True)
def solve_reduced_velocity(rhs_Nm: float, c_lin_Nms_rad: float, dq_guess_rad_s: float, tau_fc_Nm: float,
                           zeta_s: float, zeta_c: float, eta_s_rad_s: float, alpha_s_rad: float,
                           b_vis_Nms_rad: float) -> float:
    """Root v of ``c_lin v + tau_hat(v) = rhs`` [rad/s], safeguarded Newton from ``dq_guess``.

    ``c_lin + b_vis`` must be > 0; the root is bracketed by ``(rhs -/+ zmax tau_fc) / (c_lin + b_vis)``.
    Returns NaN if ``c_lin + b_vis <= 0``.
    """
    c_tot = c_lin_Nms_rad + b_vis_Nms_rad
    if not c_tot > 0.0:
        return math.nan
    f_max = max(abs(zeta_s), abs(zeta_c)) * abs(tau_fc_Nm)
    lo = (rhs_Nm - f_max) / c_tot
    hi = (rhs_Nm + f_max) / c_tot
    if hi - lo <= 0.0:
        return lo
    v = min(max(dq_guess_rad_s, lo), hi)
    scale = abs(rhs_Nm) + f_max + 1e-12
    for _ in range(200):
        g = c_lin_Nms_rad * v + stribeck_friction_Nm(v, tau_fc_Nm, zeta_s, zeta_c, eta_s_rad_s,
                                                     alpha_s_rad, b_vis_Nms_rad) - rhs_Nm
        if abs(g) <= 1e-13 * scale:
            return v
        if g < 0.0:
            lo = v
        else:
            hi = v
        dg = c_lin_Nms_rad + stribeck_friction_slope(v, tau_fc_Nm, zeta_s, zeta_c, eta_s_rad_s,
                                                     alpha_s_rad, b_vis_Nms_rad)
        v_new = v - g / dg if dg > 0.0 else 0.5 * (lo + hi)
        if not (lo < v_new < hi):
            v_new = 0.5 * (lo + hi)
        if abs(v_new - v) <= 1e-15 * (1.0 + abs(v)) or hi - lo <= 1e-15 * (1.0 + abs(v)):
            return v_new
        v = v_new
    return v


@njit(cache=True)
def reduced_step(q_rad: float, dq_prev_rad_s: float, tau_in_Nm: float, dt_s: float, rho: float,
                 tau_fc_Nm: float, zeta_s: float, zeta_c: float, eta_s_rad_s: float, alpha_s_rad: float,
                 b_vis_Nms_rad: float, gamma_Nms_rad: float, k_out_Nm_rad: float,
                 b_out_Nms_rad: float) -> tuple[float, float]:
    """One backward-Euler step of eq (20) with the testbed output ``tau_out = k_out q + b_out dq``.

    Solves ``(gamma + b_out + k_out dt) v + tau_hat(v) = rho tau_in - k_out q`` for the new
    velocity v and returns ``(q + dt v, v)`` [rad, rad/s]. ``tau_out = k_out q_new + b_out v``.
    """
    c_lin = gamma_Nms_rad + b_out_Nms_rad + k_out_Nm_rad * dt_s
    v = solve_reduced_velocity(rho * tau_in_Nm - k_out_Nm_rad * q_rad, c_lin, dq_prev_rad_s, tau_fc_Nm,
                               zeta_s, zeta_c, eta_s_rad_s, alpha_s_rad, b_vis_Nms_rad)
    return q_rad + dt_s * v, v


@njit(cache=True)
def _simulate_testbed(t_s, tau_in_Nm, q0, rho, tau_fc, zs, zc, eta, alpha, bvis, gamma, k_out, b_out,
                      q_out, dq_out, tau_out):
    n = t_s.shape[0]
    q = q0
    v = 0.0
    q_out[0] = q
    dq_out[0] = 0.0
    tau_out[0] = k_out * q
    for i in range(1, n):
        dt = t_s[i] - t_s[i - 1]
        q, v = reduced_step(q, v, tau_in_Nm[i], dt, rho, tau_fc, zs, zc, eta, alpha, bvis, gamma, k_out, b_out)
        if not math.isfinite(v):
            return i
        q_out[i] = q
        dq_out[i] = v
        tau_out[i] = k_out * q + b_out * v
    return n


@njit(cache=True)
def _simulate_given_output(t_s, tau_in_Nm, tau_out_Nm, q0, rho, tau_fc, zs, zc, eta, alpha, bvis, gamma,
                           q_out, dq_out):
    n = t_s.shape[0]
    q = q0
    v = 0.0
    q_out[0] = q
    v = solve_reduced_velocity(rho * tau_in_Nm[0] - tau_out_Nm[0], gamma, v, tau_fc, zs, zc, eta, alpha, bvis)
    dq_out[0] = v
    for i in range(1, n):
        dt = t_s[i] - t_s[i - 1]
        v = solve_reduced_velocity(rho * tau_in_Nm[i] - tau_out_Nm[i], gamma, v, tau_fc, zs, zc, eta, alpha, bvis)
        if not math.isfinite(v):
            return i
        q = q + dt * v
        q_out[i] = q
        dq_out[i] = v
    return n


@dataclass(frozen=True)
class ReducedModel:
    """Eq (20) torsional unit with the eq (21) friction and the testbed output of eq (22).

    :ivar tau_fc_Nm: nominal friction torque of eq 19 [Nm].
    :ivar stribeck: shape of the friction law (eq 21).
    :ivar gamma_Nms_rad: regularising coefficient gamma of eq (20) [Nm s/rad], >= 0.
    :ivar k_out_Nm_rad: testbed output stiffness [Nm/rad].
    :ivar b_out_Nms_rad: testbed output damping [Nm s/rad].
    :ivar rho: torque ratio r_out / r_in [-] (eq 16).
    """

    tau_fc_Nm: float
    stribeck: StribeckParams = field(default_factory=StribeckParams)
    gamma_Nms_rad: float = 0.01
    k_out_Nm_rad: float = 20.0
    b_out_Nms_rad: float = 2.0
    rho: float = 1.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.tau_fc_Nm) and self.tau_fc_Nm >= 0.0):
            raise ModelError(f"tau_fc_Nm must be finite and >= 0, got {self.tau_fc_Nm}")
        if not (self.gamma_Nms_rad >= 0.0 and self.k_out_Nm_rad >= 0.0 and self.b_out_Nms_rad >= 0.0):
            raise ModelError("gamma_Nms_rad, k_out_Nm_rad and b_out_Nms_rad must be >= 0, got "
                             f"{self.gamma_Nms_rad}, {self.k_out_Nm_rad}, {self.b_out_Nms_rad}")
        if not (math.isfinite(self.rho) and self.rho > 0.0):
            raise ModelError(f"rho (r_out / r_in) must be > 0, got {self.rho}")

    @staticmethod
    def from_pretension(T0_eq_N: float, mu: float, theta_rad: float, r_out_m: float, r_in_m: float | None = None,
                        stribeck: StribeckParams | None = None, gamma_Nms_rad: float = 0.01,
                        k_out_Nm_rad: float = 20.0, b_out_Nms_rad: float = 2.0) -> "ReducedModel":
        """Model with ``tau_fc`` from eq 19 (``mu theta T0_eq r_out``).

        :raises ModelError: on invalid arguments.
        """
        rho = 1.0 if r_in_m is None else float(r_out_m) / float(r_in_m)
        return ReducedModel(nominal_friction_torque_Nm(T0_eq_N, mu, theta_rad, r_out_m),
                            stribeck or StribeckParams(), gamma_Nms_rad, k_out_Nm_rad, b_out_Nms_rad, rho)

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], prefix: str = "reduced") -> "ReducedModel":
        """Build from ``{tau_fc_Nm, gamma_Nms_rad, k_out_Nm_rad, b_out_Nms_rad, rho, stribeck: {...}}``.

        ``tau_fc_Nm`` is required (compute it with :func:`nominal_friction_torque_Nm`).

        :raises ConfigError: on unknown keys or invalid values.
        """
        reject_unknown(cfg, {"tau_fc_Nm", "gamma_Nms_rad", "k_out_Nm_rad", "b_out_Nms_rad", "rho", "stribeck"}, prefix)
        p = f"{prefix}." if prefix else ""
        st = StribeckParams.from_mapping(section(cfg, "stribeck", prefix, required=False), f"{p}stribeck")
        return ReducedModel(
            tau_fc_Nm=get_float(cfg, "tau_fc_Nm", prefix, min_value=0.0),
            stribeck=st,
            gamma_Nms_rad=get_float(cfg, "gamma_Nms_rad", prefix, 0.01, min_value=0.0),
            k_out_Nm_rad=get_float(cfg, "k_out_Nm_rad", prefix, 20.0, min_value=0.0),
            b_out_Nms_rad=get_float(cfg, "b_out_Nms_rad", prefix, 2.0, min_value=0.0),
            rho=get_float(cfg, "rho", prefix, 1.0, min_value=0.0, min_exclusive=True),
        )

    def friction_Nm(self, dq_rad_s: float) -> float:
        """Eq (21) friction torque [Nm] at velocity ``dq_rad_s``."""
        return self.stribeck.friction_Nm(dq_rad_s, self.tau_fc_Nm)

    def simulate(self, t_s: ArrayLike, tau_in_Nm: ArrayLike, tau_out_Nm: ArrayLike | None = None,
                 q0_rad: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Simulate eq (20) over the sample times ``t_s`` from rest at ``q0_rad``.

        Testbed output (default): ``tau_out = k_out q + b_out dq`` is predicted. With
        ``tau_out_Nm`` given, the output torque is an input and only the transmission state
        is integrated (needs ``gamma + b_vis > 0``).

        :param t_s: (n,) strictly increasing sample times [s].
        :param tau_in_Nm: (n,) input torque [Nm] at those times.
        :param tau_out_Nm: optional (n,) given output torque [Nm].
        :returns: ``(q_rad, dq_rad_s, tau_out_Nm)``, each (n,).
        :raises ModelError: on mismatched/non-monotonic inputs or a degenerate model.
        :raises IntegrationError: if the implicit step fails (non-finite state).
        """
        t = np.ascontiguousarray(t_s, dtype=float)
        u = np.ascontiguousarray(tau_in_Nm, dtype=float)
        _check_series(t, u)
        n = t.size
        q = np.zeros(n)
        dq = np.zeros(n)
        s = self.stribeck
        args = (self.rho, self.tau_fc_Nm, s.zeta_s, s.zeta_c, s.eta_s_rad_s, s.alpha_s_rad, s.b_vis_Nms_rad,
                self.gamma_Nms_rad)
        if tau_out_Nm is None:
            if self.gamma_Nms_rad + self.b_out_Nms_rad + s.b_vis_Nms_rad <= 0.0 and self.k_out_Nm_rad <= 0.0:
                raise ModelError("testbed model needs gamma, b_out, b_vis or k_out > 0")
            out = np.zeros(n)
            done = _simulate_testbed(t, u, float(q0_rad), *args, self.k_out_Nm_rad, self.b_out_Nms_rad, q, dq, out)
        else:
            out = np.ascontiguousarray(tau_out_Nm, dtype=float).copy()
            if out.shape != u.shape:
                raise ModelError(f"tau_out_Nm shape {out.shape} differs from tau_in_Nm shape {u.shape}")
            if self.gamma_Nms_rad + s.b_vis_Nms_rad <= 0.0:
                raise ModelError("with a given output torque the model needs gamma_Nms_rad + b_vis_Nms_rad > 0")
            done = _simulate_given_output(t, u, out, float(q0_rad), *args, q, dq)
        if done < n:
            raise IntegrationError(f"reduced model step failed at sample {done} (t = {t[done]:.6g} s)")
        return q, dq, out

    def predict_tau_out(self, t_s: ArrayLike, tau_in_Nm: ArrayLike) -> np.ndarray:
        """Predicted testbed output torque [Nm] for the input torque series (common predictor interface)."""
        return self.simulate(t_s, tau_in_Nm)[2]


def _check_series(t: np.ndarray, u: np.ndarray) -> None:
    """:raises ModelError: unless t and u are matching finite 1-D series with t strictly increasing."""
    if t.ndim != 1 or u.shape != t.shape or t.size < 2:
        raise ModelError(f"need matching 1-D time and torque series of length >= 2, got {t.shape} and {u.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(u))):
        raise ModelError("time and torque series must be finite")
    if np.any(np.diff(t) <= 0.0):
        raise ModelError("time stamps must be strictly increasing")

