"""Standard LuGre friction (Canudas de Wit et al., 1995) for qualitative hysteresis comparison.

A lumped bristle state z [rad] (here in the joint's angular coordinate)::

    dz/dt = v - sigma0 |v| z / g(v),      g(v) = F_c + (F_s - F_c) exp(-(v / v_s)^2)
    F     = sigma0 z + sigma1 dz/dt + sigma2 v

Steady sliding: ``z -> sign(v) g(v) / sigma0`` and ``F -> sign(v) g(v) + sigma2 v`` (the
Stribeck curve plus viscous term). Pre-sliding: for small displacement from ``z = 0`` the
friction acts as a spring of stiffness ``sigma0``.

The paper (Table 2, §2) uses lumped operators only for qualitative discussion: LuGre has
no curvature, pretension field or dual-cable coupling. ``F_c`` can be set to the
reduced model's ``tau_fc`` to compare loop shapes.

Integration: for a given velocity the z equation is linear with rate ``a = sigma0 |v| / g(v)``,
so :func:`lugre_force_series` uses its exact exponential update (stable for any sigma0); the
torsional-unit simulation is semi-implicit (rate a from the previous velocity, then linear
backward Euler in v and z).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from capstan.models.common.errors import ModelError
from capstan.models.transmission.reduced import _check_series


@dataclass(frozen=True)
class LuGreParams:
    """LuGre parameters in the joint's angular coordinate.

    :ivar sigma0_Nm_rad: bristle stiffness sigma0 [Nm/rad] (pre-sliding stiffness).
    :ivar sigma1_Nms_rad: bristle damping sigma1 [Nm s/rad].
    :ivar sigma2_Nms_rad: viscous coefficient sigma2 [Nm s/rad].
    :ivar F_c_Nm: Coulomb torque [Nm].
    :ivar F_s_Nm: static (stiction) torque [Nm], >= F_c.
    :ivar v_s_rad_s: Stribeck velocity [rad/s].
    """

    sigma0_Nm_rad: float = 500.0
    sigma1_Nms_rad: float = 5.0
    sigma2_Nms_rad: float = 0.0
    F_c_Nm: float = 1.5
    F_s_Nm: float = 2.0
    v_s_rad_s: float = 0.05

    def __post_init__(self) -> None:
        if not (self.sigma0_Nm_rad > 0.0 and self.sigma1_Nms_rad >= 0.0 and self.sigma2_Nms_rad >= 0.0):
            raise ModelError("need sigma0 > 0, sigma1 >= 0, sigma2 >= 0, got "
                             f"{self.sigma0_Nm_rad}, {self.sigma1_Nms_rad}, {self.sigma2_Nms_rad}")
        if not (self.F_c_Nm > 0.0 and self.F_s_Nm >= self.F_c_Nm and self.v_s_rad_s > 0.0):
            raise ModelError(f"need F_s >= F_c > 0 and v_s > 0, got {self.F_s_Nm}, {self.F_c_Nm}, {self.v_s_rad_s}")

    def steady_state_Nm(self, v_rad_s: ArrayLike) -> np.ndarray:
        """Steady-sliding friction ``sign(v) g(v) + sigma2 v`` [Nm]."""
        v = np.asarray(v_rad_s, dtype=float)
        g = self.F_c_Nm + (self.F_s_Nm - self.F_c_Nm) * np.exp(-(v / self.v_s_rad_s) ** 2)
        return np.sign(v) * g + self.sigma2_Nms_rad * v

    def _args(self) -> tuple[float, float, float, float, float, float]:
        return (self.sigma0_Nm_rad, self.sigma1_Nms_rad, self.sigma2_Nms_rad, self.F_c_Nm, self.F_s_Nm,
                self.v_s_rad_s)


@njit(cache=True)
def lugre_g_Nm(v: float, F_c: float, F_s: float, v_s: float) -> float:
    """Stribeck curve g(v) [Nm]."""
    x = v / v_s
    return F_c + (F_s - F_c) * math.exp(-x * x)


@njit(cache=True)
def lugre_z_update(z: float, v: float, dt: float, sigma0: float, F_c: float, F_s: float, v_s: float) -> float:
    """Exact update of the bristle state over ``dt`` at constant velocity ``v``."""
    a = sigma0 * abs(v) / lugre_g_Nm(v, F_c, F_s, v_s)
    if a * dt < 1e-12:
        return z + v * dt
    z_ss = v / a
    return z_ss + (z - z_ss) * math.exp(-a * dt)


@njit(cache=True)
def _force_series(t, v, z0, sigma0, sigma1, sigma2, F_c, F_s, v_s, F, z_out):
    z = z0
    z_out[0] = z
    F[0] = sigma0 * z + sigma1 * (v[0] - sigma0 * abs(v[0]) * z / lugre_g_Nm(v[0], F_c, F_s, v_s)) + sigma2 * v[0]
    for i in range(1, t.shape[0]):
        dt = t[i] - t[i - 1]
        z = lugre_z_update(z, v[i], dt, sigma0, F_c, F_s, v_s)
        dz = v[i] - sigma0 * abs(v[i]) * z / lugre_g_Nm(v[i], F_c, F_s, v_s)
        z_out[i] = z
        F[i] = sigma0 * z + sigma1 * dz + sigma2 * v[i]


def lugre_force_series(params: LuGreParams, t_s: ArrayLike, v_rad_s: ArrayLike,
                       z0_rad: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Friction torque for a prescribed velocity series (velocity held over each step).

    :returns: ``(F_Nm, z_rad)``, each (n,).
    :raises ModelError: on mismatched or non-monotonic series.
    """
    t = np.ascontiguousarray(t_s, dtype=float)
    v = np.ascontiguousarray(v_rad_s, dtype=float)
    _check_series(t, v)
    F, z = np.zeros(t.size), np.zeros(t.size)
    _force_series(t, v, float(z0_rad), *params._args(), F, z)
    return F, z


@njit(cache=True)
def _simulate_unit(t, tau_in, rho, gamma, k_out, b_out, sigma0, sigma1, sigma2, F_c, F_s, v_s,
                   q_out, dq_out, tau_out, F_out):
    q = 0.0
    z = 0.0
    v = 0.0
    for i in range(1, t.shape[0]):
        h = t[i] - t[i - 1]
        a = sigma0 * abs(v) / lugre_g_Nm(v, F_c, F_s, v_s)
        # z_new = (z + h v) / (1 + h a) = z0c + z1c v
        z0c = z / (1.0 + h * a)
        z1c = h / (1.0 + h * a)
        # gamma v + b_out v + k_out (q + h v) + sigma0 z_new + sigma1 (z_new - z)/h + sigma2 v = rho tau_in
        lin = gamma + b_out + k_out * h + sigma2 + (sigma0 + sigma1 / h) * z1c
        rhs = rho * tau_in[i] - k_out * q - (sigma0 + sigma1 / h) * z0c + sigma1 * z / h
        v = rhs / lin
        z_new = z0c + z1c * v
        F_out[i] = sigma0 * z_new + sigma1 * (z_new - z) / h + sigma2 * v
        z = z_new
        q = q + h * v
        q_out[i] = q
        dq_out[i] = v
        tau_out[i] = k_out * q + b_out * v


def simulate_lugre_unit(params: LuGreParams, t_s: ArrayLike, tau_in_Nm: ArrayLike, gamma_Nms_rad: float = 0.01,
                        k_out_Nm_rad: float = 20.0, b_out_Nms_rad: float = 2.0,
                        rho: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Eq (20)'s torsional unit with LuGre friction in place of eq (21), testbed output, from rest.

    :returns: ``(q_rad, dq_rad_s, tau_out_Nm, friction_Nm)``, each (n,).
    :raises ModelError: on invalid series or a degenerate unit (no damping/stiffness at all).
    """
    t = np.ascontiguousarray(t_s, dtype=float)
    u = np.ascontiguousarray(tau_in_Nm, dtype=float)
    _check_series(t, u)
    if min(gamma_Nms_rad, k_out_Nm_rad, b_out_Nms_rad) < 0.0:
        raise ModelError("gamma_Nms_rad, k_out_Nm_rad and b_out_Nms_rad must be >= 0")
    out = [np.zeros(t.size) for _ in range(4)]
    _simulate_unit(t, u, float(rho), float(gamma_Nms_rad), float(k_out_Nm_rad), float(b_out_Nms_rad),
                   *params._args(), *out)
    return out[0], out[1], out[2], out[3]
