"""Multi-start least-squares identification of a torque predictor's parameters.

One local least-squares run (:func:`capstan.models.transmission.baselines.fit_parameters`)
from one starting point can stop in a local minimum: the reduced model's Stribeck shape and
its friction magnitude trade off against each other, and the gated baselines have flat
regions wherever the threshold does not change which samples stick. :func:`fit_multistart`
runs the same local fit from the model's own values and from ``n_starts - 1`` further points
of a Latin hypercube over the bounds (:class:`scipy.stats.qmc.LatinHypercube`, seeded;
log-uniform along a parameter whose bounds are positive and span more than a decade), keeps
the lowest residual, and returns every start so the spread can be reported: the RMSE range
over the starts and the parameter range over the starts that land within ``near`` of the
best RMSE (several such starts with different parameters = the data do not pin them down).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike

from capstan.models.common.errors import ModelError
from capstan.models.transmission.baselines import TorquePredictor, fit_parameters, parameter_values, with_parameters


@dataclass(frozen=True)
class MultiStartFit:
    """Result of :func:`fit_multistart`.

    :ivar model: the predictor with the best parameters.
    :ivar rmse_Nm: its output-torque RMSE on the fitted run [Nm].
    :ivar names: the fitted parameter names.
    :ivar starts: (n_starts, n_params) starting points.
    :ivar params: (n_starts, n_params) parameters each start converged to.
    :ivar rmse_starts_Nm: (n_starts,) RMSE each start reached [Nm].
    :ivar near: relative RMSE margin defining the near-best starts [-].
    """

    model: Any
    rmse_Nm: float
    names: tuple[str, ...]
    starts: np.ndarray
    params: np.ndarray
    rmse_starts_Nm: np.ndarray
    near: float

    @property
    def near_best(self) -> np.ndarray:
        """Boolean mask of the starts whose RMSE is within ``near`` of the best."""
        return self.rmse_starts_Nm <= self.rmse_Nm * (1.0 + self.near)

    def parameter_ranges(self) -> dict[str, tuple[float, float]]:
        """Per parameter, (min, max) over the near-best starts."""
        p = self.params[self.near_best]
        return {n: (float(p[:, i].min()), float(p[:, i].max())) for i, n in enumerate(self.names)}

    def summary(self) -> dict[str, Any]:
        """Plain-JSON summary: best RMSE, RMSE range over starts, near-best count and parameter ranges."""
        ok = self.rmse_starts_Nm[np.isfinite(self.rmse_starts_Nm)]
        return {"rmse_Nm": self.rmse_Nm, "n_starts": int(self.rmse_starts_Nm.size),
                "rmse_starts_min_Nm": float(ok.min()), "rmse_starts_max_Nm": float(ok.max()),
                "near": self.near, "n_near_best": int(self.near_best.sum()),
                "parameter_ranges_near_best": {k: list(v) for k, v in self.parameter_ranges().items()},
                "best": dict(zip(self.names, parameter_values(self.model, self.names).tolist()))}


def start_points(lower: Sequence[float], upper: Sequence[float], n: int, seed: int = 0) -> np.ndarray:
    """``n`` Latin-hypercube points inside finite bounds (log-uniform where ``0 < lower`` and ``upper > 10 lower``).

    :raises ModelError: on infinite, reversed or mismatched bounds, or ``n < 1``.
    """
    from scipy.stats import qmc

    lo = np.asarray(lower, dtype=float)
    hi = np.asarray(upper, dtype=float)
    if lo.shape != hi.shape or lo.ndim != 1 or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ModelError(f"multi-start needs finite bounds of equal length, got {lower}, {upper}")
    if np.any(hi <= lo):
        raise ModelError(f"every upper bound must exceed its lower bound, got {lower}, {upper}")
    if n < 1:
        raise ModelError(f"need at least one start, got {n}")
    unit = qmc.LatinHypercube(d=lo.size, seed=seed).random(n)
    logscale = (lo > 0.0) & (hi > 10.0 * lo)
    pts = lo + unit * (hi - lo)
    if np.any(logscale):
        pts[:, logscale] = np.exp(np.log(lo[logscale]) + unit[:, logscale] * np.log(hi[logscale] / lo[logscale]))
    return pts


def fit_multistart(model: TorquePredictor, names: Sequence[str], t_s: ArrayLike, tau_in_Nm: ArrayLike,
                   tau_out_meas_Nm: ArrayLike, lower: Sequence[float], upper: Sequence[float],
                   n_starts: int = 8, seed: int = 0, near: float = 0.02) -> MultiStartFit:
    """Fit ``names`` of ``model`` from its own values and ``n_starts - 1`` hypercube points.

    :param near: starts within this relative RMSE margin of the best count as near-best [-].
    :raises ModelError: on bad bounds or names, or when no start gives a finite fit.
    """
    names = tuple(names)
    x_model = np.clip(parameter_values(model, names), np.asarray(lower, float), np.asarray(upper, float))
    starts = np.vstack([x_model[None, :], start_points(lower, upper, n_starts - 1, seed)]) if n_starts > 1 \
        else x_model[None, :]
    params = np.full(starts.shape, math.nan)
    rmses = np.full(starts.shape[0], math.nan)
    best: tuple[float, Any] | None = None
    for i, x0 in enumerate(starts):
        fitted, r = fit_parameters(with_parameters(model, names, x0), names, t_s, tau_in_Nm, tau_out_meas_Nm,
                                   lower=lower, upper=upper)
        params[i] = parameter_values(fitted, names)
        rmses[i] = r
        if math.isfinite(r) and (best is None or r < best[0]):
            best = (r, fitted)
    if best is None:
        raise ModelError(f"no start of the {len(starts)} gave a finite fit of {list(names)}")
    return MultiStartFit(best[1], best[0], names, starts, params, rmses, float(near))


__all__ = ["MultiStartFit", "fit_multistart", "start_points"]
