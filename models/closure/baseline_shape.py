"""The baseline friction law as a regression: its design matrix, and the joint fit of its
nonlinear shape (alpha, eta_s) with its linear parameters and any extra columns.

For a given shape the prediction is linear in the parameters::

    tau_out = [B(tau_in, dq_out, alpha, eta_s), F_1, ..., F_k] @ theta

(:func:`friction_basis`; the F are extra bases, the closure's effects). The shape is
found by variable projection: a log grid of starting points (relative to the 95th
percentile of |dq|) plus a given start, and a bounded Gauss-Newton refinement from the
best few of them -- the SSE over the shape has side valleys.

Physical domain of the reduced model (eq 21, as :class:`capstan.models.transmission.reduced.StribeckParams`
enforces): the static friction exceeds the Coulomb level, zeta_s >= zeta_c = 1, so the
stiction excess tau_fc (zeta_s - 1) is kept >= 0 (an exact bound-constrained solve:
when the free solution has it negative, the optimum lies on the bound). Without the
bound a negative "Stribeck" term with a wide eta_s rebuilds friction that *rises* with
speed (tau_fc (dq/eta_s)^2 for dq << eta_s) and swallows drag the model does not have.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import least_squares

from capstan.models.common.errors import ModelError

#: column indices of B that depend on the shape (tanh and Stribeck/load columns)
_VAR = (1, 2)
#: starting grid of a refit (``n_alpha`` x ``n_eta``): alpha * v95 over 2-1000 and
#: eta_s / v95 over 0.01-1, log-spaced
N_ALPHA, N_ETA = 5, 4
#: refinements from the best starting points
N_REFINE = 3


class ModelKind(IntEnum):
    """Which transmission model ``identify`` fits."""

    REDUCED = 0
    WU = 1
    DISTRIBUTED = 2

    @staticmethod
    def parse(name: str) -> "ModelKind":
        """``"reduced" | "wu" | "distributed"`` -> ModelKind.

        :raises ModelError: for an unknown name.
        """
        try:
            return ModelKind[name.upper()]
        except KeyError:
            raise ModelError(f"unknown model {name!r}; one of reduced, wu, distributed") from None


_LIN_NAMES = {ModelKind.REDUCED: ("ratio", "tau_fc_Nm", "stiction_excess_Nm", "b_vis_Nms_rad", "offset_Nm"),
              ModelKind.WU: ("ratio", "tau_c_Nm", "k_load", "b_vis_Nms_rad", "offset_Nm")}


def linear_param_names(kind: ModelKind) -> tuple[str, ...]:
    """Names of the baseline's linear parameters, in the column order of :func:`friction_basis`.

    :raises KeyError: for the distributed model (not fitted here).
    """
    return _LIN_NAMES[kind]


def named_params(kind: ModelKind, theta: np.ndarray, alpha_s_rad: float, eta_s_rad_s: float) -> dict[str, float]:
    """The baseline's parameters by name from its linear parameters and shape
    (``zeta_s`` = 1 + excess / tau_fc for the reduced model)."""
    out = {nm: float(theta[i]) for i, nm in enumerate(_LIN_NAMES[kind])}
    out["alpha_s_rad"] = float(alpha_s_rad)
    if kind == ModelKind.REDUCED:
        out["eta_s_rad_s"] = float(eta_s_rad_s)
        if theta[1] != 0.0:
            out["zeta_s"] = float(1.0 + theta[2] / theta[1])
    return out


def friction_basis(kind: ModelKind, v: np.ndarray, tau_in: np.ndarray, alpha_s_rad: float,
                   eta_s_rad_s: float) -> np.ndarray:
    """Design matrix of the baseline (columns match ``_LIN_NAMES[kind]``)."""
    th = np.tanh(alpha_s_rad * v)
    if kind == ModelKind.REDUCED:
        second = -th * np.exp(-(v / eta_s_rad_s) ** 2)
    else:
        second = -th * np.abs(tau_in)
    return np.column_stack([tau_in, -th, second, -v, np.ones_like(v)])


def _col_scale(X: np.ndarray) -> np.ndarray:
    return np.maximum(np.sqrt((X ** 2).mean(axis=0)), 1e-12)


@dataclass
class ShapeFit:
    """Result of :func:`fit_shape`.

    :ivar theta: the baseline's 5 linear parameters (order of :func:`friction_basis`)
        followed by the extra columns'.
    :ivar sse: training sum of squared residuals [Nm^2].
    """

    alpha_s_rad: float
    eta_s_rad_s: float
    theta: np.ndarray
    sse: float


def design(kind: ModelKind, tau_in_Nm: np.ndarray, dq_rad_s: np.ndarray, alpha_s_rad: float,
           eta_s_rad_s: float, extra: np.ndarray | None = None) -> np.ndarray:
    """Design matrix [B, extra] of the augmented model (n x (5 + k))."""
    B = friction_basis(kind, dq_rad_s, tau_in_Nm, alpha_s_rad, eta_s_rad_s)
    return B if extra is None or extra.shape[1] == 0 else np.hstack([B, extra])


class ShapeProblem:
    """Variable projection of the baseline (+ extra columns) on fixed data.

    The columns that do not depend on the shape (S: tau_in, -dq, 1 and the extras) are
    scaled and their ridge-regularised Gram matrix C factorised once; each shape then
    only needs the small Schur complement of the shape columns V (the normal equations
    [[V'V, V'S], [S'V, C]] solved blockwise), whatever the number of extras.

    :param ridge_extra: per extra column, True for a ridge of ``ridge * n`` (smooth curves).
    """

    def __init__(self, kind: ModelKind, tau_in_Nm: np.ndarray, dq_rad_s: np.ndarray, y_Nm: np.ndarray,
                 extra: np.ndarray | None = None, ridge_extra: np.ndarray | None = None, ridge: float = 0.0) -> None:
        n = y_Nm.shape[0]
        extra = np.zeros((n, 0)) if extra is None else extra
        ridge_extra = np.zeros(extra.shape[1], bool) if ridge_extra is None else ridge_extra
        self.kind, self.tau_in, self.v, self.y, self.n = kind, tau_in_Nm, dq_rad_s, y_Nm, n
        S = np.hstack([np.column_stack([tau_in_Nm, -dq_rad_s, np.ones(n)]), extra])
        self.s_scale = _col_scale(S)
        self.Ss = S / self.s_scale
        C = self.Ss.T @ self.Ss
        rid = np.concatenate([np.zeros(3), np.asarray(ridge_extra, float)])
        C[np.diag_indices_from(C)] += 1e-10 * n + ridge * n * rid
        try:
            fac = cho_factor(C)
            self._solve_C = lambda b: cho_solve(fac, b)
        except np.linalg.LinAlgError:
            Cinv = np.linalg.pinv(C)
            self._solve_C = lambda b: Cinv @ b
        self.xS0 = self._solve_C(np.einsum("ij,i->j", self.Ss, y_Nm))

    def _blockwise(self, Vs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # thin products by einsum: a threaded BLAS is slow on (2 x n) @ (n x k) when cores are busy
        A = np.einsum("ij,ik->jk", Vs, Vs) + 1e-10 * self.n * np.eye(Vs.shape[1])
        Bt = np.einsum("ij,ik->jk", self.Ss, Vs)            # S'V
        W = self._solve_C(Bt)                                # C^-1 S'V
        K = A - Bt.T @ W
        rhs = np.einsum("ij,i->j", Vs, self.y) - Bt.T @ self.xS0
        try:
            xV = np.linalg.solve(K, rhs)
        except np.linalg.LinAlgError:
            xV = np.linalg.lstsq(K, rhs, rcond=None)[0]
        return xV, self.xS0 - W @ xV

    def solve(self, alpha_s_rad: float, eta_s_rad_s: float) -> tuple[np.ndarray, np.ndarray]:
        """(theta in the order of [B, extra], training residual [Nm]) for a given shape."""
        B = friction_basis(self.kind, self.v, self.tau_in, alpha_s_rad, eta_s_rad_s)
        V = B[:, list(_VAR)]
        vs = _col_scale(V)
        Vs = V / vs
        xV, xS = self._blockwise(Vs)
        if self.kind == ModelKind.REDUCED and xV[1] < 0.0:     # stiction excess on its bound 0
            x1, xS = self._blockwise(Vs[:, :1])
            xV = np.array([x1[0], 0.0])
        r = self.y - Vs @ xV - np.einsum("ij,j->i", self.Ss, xS)
        c = np.concatenate([xV / vs, xS / self.s_scale])
        theta = np.concatenate([[c[2], c[0], c[1], c[3], c[4]], c[5:]])
        return theta, r


def fit_shape(prob: ShapeProblem, v95_rad_s: float, start: tuple[float, float] | None = None,
              n_alpha: int = N_ALPHA, n_eta: int = N_ETA) -> ShapeFit:
    """Fit the shape (alpha [s/rad], eta_s [rad/s]) and the linear parameters jointly.

    Starting points: ``start`` (if given) and a log grid of ``n_alpha`` x ``n_eta``
    (alpha * v95 over 2-1000, eta_s / v95 over 0.01-1; ``v95_rad_s`` the 95th percentile
    of |dq|); the best ``N_REFINE`` are refined within alpha * v95 in [0.5, 5e4] and
    eta_s / v95 in [1e-3, 5]. For the ``wu`` model only alpha is free. The training SSE
    is never worse than at the best starting point.

    :raises ModelError: if ``v95_rad_s`` is not positive (no motion).
    """
    if not v95_rad_s > 0.0:
        raise ModelError("the runs carry no motion (velocity is zero); nothing to identify")
    reduced = prob.kind == ModelKind.REDUCED
    lo = [math.log(0.5 / v95_rad_s), math.log(1e-3 * v95_rad_s)]
    hi = [math.log(5e4 / v95_rad_s), math.log(5.0 * v95_rad_s)]
    le_fixed = math.log(start[1]) if start is not None else math.log(0.1 * v95_rad_s)

    def sse(la: float, le: float) -> float:
        r = prob.solve(math.exp(la), math.exp(le))[1]
        return float(np.einsum("i,i->", r, r))    # not r @ r: a threaded BLAS dot is slow on busy cores

    starts = [] if start is None else [(sse(math.log(start[0]), le_fixed), math.log(start[0]), le_fixed)]
    for a_rel in np.logspace(0.3, 3.0, n_alpha):
        for e_rel in (np.logspace(-2.0, 0.0, n_eta) if reduced else [math.nan]):
            la = math.log(a_rel / v95_rad_s)
            le = math.log(e_rel * v95_rad_s) if reduced else le_fixed
            starts.append((sse(la, le), la, le))
    starts.sort(key=lambda x: x[0])
    best = starts[0]
    for _, la_s, le_s in starts[:N_REFINE]:
        x0 = np.clip([la_s, le_s], lo, hi)
        if reduced:
            res = least_squares(lambda x: prob.solve(math.exp(x[0]), math.exp(x[1]))[1], x0, method="trf",
                                max_nfev=40, bounds=(lo, hi))
            la, le = float(res.x[0]), float(res.x[1])
        else:
            res = least_squares(lambda x: prob.solve(math.exp(x[0]), math.exp(le_fixed))[1], x0[:1], method="trf",
                                max_nfev=40, bounds=(lo[:1], hi[:1]))
            la, le = float(res.x[0]), le_fixed
        s = sse(la, le)
        if s < best[0]:
            best = (s, la, le)
    s, la, le = best
    theta, _ = prob.solve(math.exp(la), math.exp(le))
    return ShapeFit(math.exp(la), math.exp(le), theta, s)
