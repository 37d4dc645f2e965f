"""The reduced model's friction (paper eq 21) from a link-free run.

With the link free, the transmission's torque loss ``rho tau_in - tau_out`` (rho = r_out / r_in,
both torques from the load cells) is the friction the controller's feedforward compensates:
``tau_f(dq_out) = tanh(alpha dq) [1 + (zeta_s - 1) exp(-(dq / eta_s)^2)] tau_fc + b_vis dq`` on
the link's rate (the IMU angle, filtered and differentiated). The shape (alpha, eta_s) is found
by variable projection (a log grid, then a Nelder-Mead refinement; for each shape the magnitudes
tau_fc, the stiction excess, b_vis and an offset are a linear least-squares solve), with the
closure's design matrix :func:`capstan.models.closure.identification.friction_basis` and
block-sandwich standard errors.

Fitting the loss directly (the ratio fixed by the pulleys) rather than ``tau_out`` on ``tau_in``
with a free ratio: on a free link both torques follow its gravity together, so a free ratio
trades against the friction (:func:`capstan.models.closure.identification.fit_baseline` does
that on testbed runs, where the environment decorrelates them).

The magnitude scales with the pretension and the bending (eq 19, ``tau_fc = mu theta T0_eq r_out``):
the pretension is measured (the load cells' mean; ``T0_eq`` is a per-cable sum of two tensions,
so ~2x that mean), the bending comes from the drawings, and ``mu`` follows (first order; the controller's own pretension
field turns tau_fc into its ``mu`` exactly, see ``controller/law/tuning/``).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize

from capstan.models.closure.identification import ModelKind, friction_basis, sandwich_cov
from capstan.models.common.errors import ModelError
from capstan.models.rig_id.fits import Estimate, _lowpass, _trim, link_angle_rad
from capstan.models.rig_id.runs import RigRun


def _design(v: np.ndarray, alpha: float, eta: float) -> np.ndarray:
    """[tanh, Stribeck excess, v, 1] (signs as the friction torque, not as its effect on tau_out)."""
    B = friction_basis(ModelKind.REDUCED, v, np.zeros_like(v), alpha, eta)
    return np.column_stack([-B[:, 1], -B[:, 2], -B[:, 3], B[:, 4]])


def _solve(v: np.ndarray, y: np.ndarray, alpha: float, eta: float) -> tuple[np.ndarray, float]:
    B = _design(v, alpha, eta)
    th, *_ = np.linalg.lstsq(B, y, rcond=None)
    r = y - B @ th
    return th, float(r @ r)


def fit_friction(run: RigRun, theta_rad: float, cutoff_hz: float = 20.0) -> dict[str, Estimate]:
    """Reduced-model friction and the pretension it scales with, from a link-free run.

    :param theta_rad: the sheath's total bending from the drawings [rad].
    :returns: ``tau_fc`` [Nm], ``zeta_s``, ``eta_s_rad_s``, ``alpha_s_rad`` [s/rad], ``b_vis``
        [Nm s/rad], ``T0`` [N] (load cells' mean), ``mu_theta`` and ``mu``.
    :raises ModelError: if the link hardly moved.
    """
    dt = run.dt_s
    sl = _trim(len(run))
    rho = run.r_out_m / run.r_in_m
    y = _lowpass(rho * run.tau_in_Nm - run.tau_out_Nm, cutoff_hz, dt)[sl]
    v = np.gradient(_lowpass(link_angle_rad(run), cutoff_hz, dt), dt)[sl]
    v95 = float(np.percentile(np.abs(v), 95))
    if v95 < 0.02:
        raise ModelError(f"free run: the link's rate reached only {v95:.3f} rad/s (95th percentile); "
                         "friction needs sliding above 0.02 rad/s")
    grid = [(a, e) for a in np.geomspace(2.0 / v95, 2000.0 / v95, 13) for e in np.geomspace(0.02 * v95, v95, 8)]
    a0, e0 = min(grid, key=lambda ae: _solve(v, y, *ae)[1])
    res = minimize(lambda p: _solve(v, y, math.exp(p[0]), math.exp(p[1]))[1], [math.log(a0), math.log(e0)],
                   method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-9, "maxiter": 200})
    alpha, eta = math.exp(res.x[0]), math.exp(res.x[1])
    th, sse = _solve(v, y, alpha, eta)
    B = _design(v, alpha, eta)
    cols = [B]
    for da, de in ((1e-4, 0.0), (0.0, 1e-4)):
        Bp = _design(v, alpha * math.exp(da), eta * math.exp(de))
        cols.append(((Bp - B) @ th / 1e-4)[:, None])
    J = np.hstack(cols)
    cov = sandwich_cov(J, y - B @ th)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    how = f"free: rho tau_in - tau_out = eq 21 on the IMU rate, rmse {math.sqrt(sse / len(y)):.3f} Nm"
    tau_fc = Estimate(float(th[0]), float(se[0]), "Nm", how)
    zeta = 1.0 + th[1] / th[0] if th[0] != 0.0 else 1.0
    gz = np.array([-th[1] / th[0] ** 2, 1.0 / th[0], 0, 0, 0, 0]) if th[0] != 0.0 else np.zeros(6)
    t = run.mean_tension_N[sl]
    T0 = Estimate(float(np.mean(t)), float(np.std(t) / math.sqrt(max(len(t) / 1000.0, 1.0))), "N",
                  "mean of the four load cells over the free run")
    mt = tau_fc.value / (2.0 * T0.value * run.r_out_m)     # T0_eq is a per-cable sum of two tensions
    mt_se = abs(mt) * math.hypot(tau_fc.rel_stderr, T0.rel_stderr)
    return {
        "tau_fc": tau_fc,
        "zeta_s": Estimate(float(zeta), float(math.sqrt(max(gz @ cov @ gz, 0.0))), "-", how),
        "eta_s_rad_s": Estimate(eta, eta * float(se[5]), "rad/s", how),
        "alpha_s_rad": Estimate(alpha, alpha * float(se[4]), "s/rad", how),
        "b_vis": Estimate(float(th[2]), float(se[2]), "Nm s/rad", how),
        "T0": T0,
        "mu_theta": Estimate(mt, mt_se, "-", "tau_fc / (T0_eq r_out) (eq 19), T0_eq ~ 2 x the load cells' mean"),
        "mu": Estimate(mt / theta_rad, mt_se / theta_rad, "-", f"mu_theta / theta, theta = {theta_rad:g} rad from the drawings"),
    }
