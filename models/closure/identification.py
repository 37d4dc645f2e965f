"""Fit the transmission model's free parameters to measured runs, with uncertainties.

Prediction form (all models): the *friction-on-measured-velocity* form the
controller's feedforward uses, evaluated on measured signals, predicting the output
torque from the input torque::

    tau_out = g tau_in - tau_f(dq_out) + c

``reduced`` (paper eq 20/21, the project's model): tau_f is the Stribeck-Coulomb-viscous
law (21) with tau_fc the friction magnitude (eq 19, mu theta T0_eq r), zeta_s the
stiction ratio, eta_s the Stribeck velocity, alpha the tanh steepness, b_vis the
viscous term (which absorbs gamma of eq 20), g the transmission ratio r_out/r_in and c
a torque-sensor offset. Free: g, tau_fc, zeta_s, b_vis, c (linear, solved exactly for
given shape) and alpha, eta_s (nonlinear, variable projection, :mod:`capstan.models.closure.baseline_shape`),
within the law's domain zeta_s >= 1 (the stiction excess tau_fc (zeta_s - 1) >= 0).
``wu`` (Wu-type analytical mapping with uniform pretension): Coulomb friction with a
load-proportional part, tau_f = tanh(alpha dq)(tau_c + k_load |tau_in|) + b_vis dq.
``distributed`` is not fitted here (its states are not observable from these signals);
asking for it raises :class:`ModelError`.

Elastic path (only if q_in and q_out are measured): for the dual-cable pull-pull
transmission the two cable-tension sums give (tau_in + tau_out)/2 = K_c (q_in - rho q_out)
exactly for N = 1, so ``tau_out = 2 K_c defl - tau_in + c_el`` identifies the torsional
stiffness K_c and the angle ratio rho. The testbed environment tau_out = k_out q_out +
b_out dq_out + c (eq 22) is fitted too and reported with its R^2.

Uncertainties: Gauss-Newton covariance with a block-sandwich correction
(A^-1 (sum_b J_b^T r_b r_b^T J_b) A^-1 over contiguous ~1 s blocks), which stays honest
when the residual is autocorrelated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from capstan.models.closure.baseline_shape import (ModelKind, ShapeProblem, fit_shape, friction_basis, linear_param_names,
                                   named_params)
from capstan.models.common.errors import ModelError
from capstan.models.closure.signals import Signals

__all__ = ["BaselineFit", "ModelKind", "fit_baseline", "fit_elastic", "fit_environment", "friction_basis",
           "linear_param_names", "named_params", "sandwich_cov"]


@dataclass
class BaselineFit:
    """A fitted baseline model.

    :ivar params: named parameters (SI; ``zeta_s`` dimensionless).
    :ivar stderr: one standard error per parameter (block-sandwich).
    :ivar rmse_Nm: fit RMSE on the data it was fitted to [Nm].
    """

    kind: ModelKind
    alpha_s_rad: float
    eta_s_rad_s: float
    theta: np.ndarray
    params: dict[str, float] = field(default_factory=dict)
    stderr: dict[str, float] = field(default_factory=dict)
    rmse_Nm: float = math.nan
    max_err_Nm: float = math.nan
    n_samples: int = 0
    extra: dict[str, dict[str, float]] = field(default_factory=dict)

    def basis(self, sig: Signals) -> np.ndarray:
        """Baseline design matrix on ``sig`` (n x 5)."""
        return friction_basis(self.kind, sig.dq_out_rad_s, sig.tau_in_Nm, self.alpha_s_rad, self.eta_s_rad_s)

    def predict(self, sig: Signals) -> np.ndarray:
        """Predicted tau_out [Nm] on ``sig``."""
        return self.basis(sig) @ self.theta

    def friction_shape(self, v: np.ndarray) -> np.ndarray:
        """Normalised friction shape s(v) = tau_f,Coulomb+Stribeck / tau_fc (odd, |s| ~ 1 when sliding)."""
        th = np.tanh(self.alpha_s_rad * v)
        if self.kind == ModelKind.REDUCED and self.theta[1] != 0.0:
            return th * (1.0 + self.theta[2] / self.theta[1] * np.exp(-(v / self.eta_s_rad_s) ** 2))
        return th


def _blocks(n: int, n_blocks: int) -> np.ndarray:
    return np.linspace(0, n, max(2, min(n_blocks, n // 20 + 2)) + 1).astype(int)


def sandwich_cov(J: np.ndarray, r: np.ndarray, n_blocks: int = 100) -> np.ndarray:
    """Block-sandwich covariance of least-squares parameters (J: n x p, r: residual)."""
    A = J.T @ J
    try:
        Ainv = np.linalg.pinv(A)
    except np.linalg.LinAlgError:      # pragma: no cover - pinv is robust
        return np.full(A.shape, np.nan)
    edges = _blocks(J.shape[0], n_blocks)
    M = np.zeros_like(A)
    for a, b in zip(edges[:-1], edges[1:]):
        g = J[a:b].T @ r[a:b]
        M += np.outer(g, g)
    return Ainv @ M @ Ainv


def _solve(B: np.ndarray, y: np.ndarray) -> np.ndarray:
    scale = np.maximum(np.sqrt((B ** 2).mean(axis=0)), 1e-12)
    sol, *_ = np.linalg.lstsq(B / scale, y, rcond=None)
    return sol / scale


def fit_baseline(sig: Signals, kind: ModelKind = ModelKind.REDUCED) -> BaselineFit:
    """Fit the baseline model to ``sig`` (predicting tau_out), with uncertainties.

    :raises ModelError: for ``distributed`` or if the data carry no motion.
    """
    if kind == ModelKind.DISTRIBUTED:
        raise ModelError("the distributed model has unobservable node states; identify fits "
                         "'reduced' (eq 20/21, from which T0_eq and the Stribeck shape follow) or 'wu'")
    v, y, tin = sig.dq_out_rad_s, sig.tau_out_Nm, sig.tau_in_Nm
    v95 = float(np.percentile(np.abs(v), 95))
    if not v95 > 0:
        raise ModelError("the runs carry no motion (velocity is zero); nothing to identify")

    prob = ShapeProblem(kind, tin, v, y)
    shape = fit_shape(prob, v95, n_alpha=10, n_eta=6)
    # a second pass from there as the closure refits the shape (same start and grid): the
    # closure's refits then start where the baseline alone has its optimum, and a
    # candidate cannot take credit for a better optimum of the baseline itself
    shape = fit_shape(prob, v95, start=(shape.alpha_s_rad, shape.eta_s_rad_s))
    theta, alpha, eta = shape.theta, shape.alpha_s_rad, shape.eta_s_rad_s
    r = y - friction_basis(kind, v, tin, alpha, eta) @ theta
    la, le = math.log(alpha), math.log(eta)
    # Jacobian of the prediction w.r.t. (theta, log alpha, log eta), for the covariance
    B = friction_basis(kind, v, tin, alpha, eta)
    cols = [B]
    for k, (dla, dle) in enumerate(((1e-4, 0.0), (0.0, 1e-4))):
        if k == 1 and kind != ModelKind.REDUCED:
            break
        Bp = friction_basis(kind, v, tin, math.exp(la + dla), math.exp(le + dle))
        cols.append(((Bp @ theta) - (B @ theta))[:, None] / 1e-4)
    J = np.hstack(cols)
    cov = sandwich_cov(J, r)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    names = linear_param_names(kind)
    fit = BaselineFit(kind, alpha, eta, theta, n_samples=len(sig),
                      rmse_Nm=float(np.sqrt(np.mean(r ** 2))), max_err_Nm=float(np.max(np.abs(r))))
    for i, nm in enumerate(names):
        fit.params[nm] = float(theta[i])
        fit.stderr[nm] = float(se[i])
    fit.params["alpha_s_rad"] = alpha
    fit.stderr["alpha_s_rad"] = float(alpha * se[5])
    if kind == ModelKind.REDUCED:
        fit.params["eta_s_rad_s"] = eta
        fit.stderr["eta_s_rad_s"] = float(eta * se[6])
        if theta[1] != 0.0:   # zeta_s = 1 + excess / tau_fc, delta method
            z = 1.0 + theta[2] / theta[1]
            gz = np.zeros(len(se))
            gz[1], gz[2] = -theta[2] / theta[1] ** 2, 1.0 / theta[1]
            fit.params["zeta_s"] = float(z)
            fit.stderr["zeta_s"] = float(math.sqrt(max(gz @ cov @ gz, 0.0)))
    fit.extra.update(fit_elastic(sig))
    fit.extra.update(fit_environment(sig))
    return fit


def fit_elastic(sig: Signals) -> dict[str, dict[str, float]]:
    """Torsional stiffness from the elastic path (needs q_in); empty dict otherwise.

    Returns ``{"elastic": {K_c_Nm_rad, K_c_Nm_rad_se, ratio_q, offset_Nm, rmse_Nm}}``.
    """
    if sig.q_in_rad is None:
        return {}
    B = np.column_stack([sig.q_in_rad, sig.q_out_rad, np.ones(len(sig))])
    y = sig.tau_out_Nm + sig.tau_in_Nm
    th = _solve(B, y)
    r = y - B @ th
    se = np.sqrt(np.clip(np.diag(sandwich_cov(B, r)), 0.0, None))
    if abs(th[0]) < 1e-12:
        return {}
    return {"elastic": {"K_c_Nm_rad": float(th[0] / 2.0), "K_c_Nm_rad_se": float(se[0] / 2.0),
                        "ratio_q": float(-th[1] / th[0]), "offset_Nm": float(th[2]),
                        "rmse_Nm": float(np.sqrt(np.mean(r ** 2)))}}


def fit_environment(sig: Signals) -> dict[str, dict[str, float]]:
    """Output environment tau_out = k_out q_out + b_out dq_out + c (eq 22), with R^2."""
    B = np.column_stack([sig.q_out_rad, sig.dq_out_rad_s, np.ones(len(sig))])
    th = _solve(B, sig.tau_out_Nm)
    r = sig.tau_out_Nm - B @ th
    se = np.sqrt(np.clip(np.diag(sandwich_cov(B, r)), 0.0, None))
    var = float(np.var(sig.tau_out_Nm))
    return {"environment": {"k_out_Nm_rad": float(th[0]), "k_out_Nm_rad_se": float(se[0]),
                            "b_out_Nms_rad": float(th[1]), "b_out_Nms_rad_se": float(se[1]),
                            "r2": float(1.0 - np.mean(r ** 2) / var) if var > 0 else 0.0}}
