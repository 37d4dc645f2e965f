"""Uncertainty of a selected in-model effect: standard errors and intervals of its parameters,
and the test of "no effect" that keeps a marginal finding out of the selection
(:func:`.closure.close_in_model`).

The effect is linearised at its joint refit with the baseline
(:class:`~capstan.models.closure.dynamic.in_model.JointFit`): the Jacobian of the training
prediction by forward differences in the baseline's free parameters, the effect's coefficients
and its numeric shape (a lag, a time constant, a change-point instant) -- one simulation of the
training runs per column (on long runs, of the contiguous training windows of
:func:`capstan.models.closure.windows.window_index`). The residual of a stick-slip simulation is
correlated over hundreds of samples, so the scores are summed over contiguous time windows
(``BLOCK_S``, never crossing a run) and:

* the covariance is the block sandwich ``A^-1 (sum_b g_b g_b^T) A^-1``, ``A = J^T J``,
  ``g_b = J_b^T r_b`` centred on their mean (:func:`sandwich`);
* the bootstrap resamples the windows (``N_BOOT`` draws, with replacement) and takes the
  Gauss-Newton step of each draw, ``-A^-1 sum_drawn g_b``, from the fit: a linearised block
  bootstrap whose draws give the intervals of any function of the parameters (the named
  parameters of the feedforward, an empirical curve's peak-to-peak over its support).

"No effect": the Wald statistic of the effect's own coefficients (the lag, for a latency)
``c^T C^-1 c`` against the chi-square quantile ``1 - ALPHA_NO_EFFECT`` with one degree per
coefficient (for one coefficient: zero within 1.96 standard errors). The test is taken with the
shape held at its fitted value (a shape means nothing at zero amplitude), the baseline free.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from capstan.models.closure import windows
from capstan.models.closure.dynamic.candidates import Refs, _named
from capstan.models.closure.dynamic.in_model import InModelCloser, JointFit
from capstan.models.closure.scoring import test_blocks

#: length of the windows the scores are summed over [s]
BLOCK_S = 0.5
#: bootstrap draws of the windows
N_BOOT = 1000
#: level of the "no effect" test (two-sided: zero inside the 95 % region is no effect)
ALPHA_NO_EFFECT = 0.05
#: relative forward-difference step of a parameter (floor ``STEP_FLOOR`` of its scale)
REL_STEP = 1e-2
#: relative step of a positive shape value (time constant, slide scale)
SHAPE_REL_STEP = 0.05


@dataclass
class EffectUncertainty:
    """The linearised uncertainty of one selected effect (module docstring).

    :ivar names: parameter names, ``base:<name>``, ``coef:<name>``, ``shape:<key>``.
    :ivar theta: the fitted values, in that order.
    :ivar cov: block-sandwich covariance of ``theta`` (shape free).
    :ivar boot: ``N_BOOT x len(theta)`` bootstrap draws of ``theta``.
    :ivar wald: the "no effect" statistic; ``dof`` its degrees of freedom; ``p_value`` its level.
    """

    names: list[str]
    theta: np.ndarray
    cov: np.ndarray
    boot: np.ndarray
    wald: float
    dof: int
    p_value: float

    @property
    def no_effect(self) -> bool:
        """True when "no effect" lies inside the ``1 - ALPHA_NO_EFFECT`` region."""
        return not self.p_value < ALPHA_NO_EFFECT

    def stderr(self, name: str) -> float:
        return float(math.sqrt(max(self.cov[self.names.index(name), self.names.index(name)], 0.0)))


def sandwich(J: np.ndarray, r: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(``A^-1``, the per-window scores ``g_b`` (windows x p), the block-sandwich covariance)
    of a least-squares fit with Jacobian ``J`` (n x p) and residual ``r`` at the fit."""
    Ainv = np.linalg.pinv(J.T @ J)
    nb = int(labels.max()) + 1
    G = np.stack([np.bincount(labels, J[:, j] * r, nb) for j in range(J.shape[1])], axis=1)
    # centred: a fit stopped short of the optimum (a bounded number of evaluations) leaves a
    # mean score, a step towards the optimum and not a spread of the estimate
    G = G - G.mean(axis=0)
    return Ainv, G, Ainv @ (G.T @ G) @ Ainv


def _numeric_shape(shape: dict) -> list[str]:
    return [k for k, v in shape.items() if isinstance(v, (int, float)) and not isinstance(v, bool)]


def effect_uncertainty(closer: InModelCloser, jf: JointFit, n_boot: int = N_BOOT,
                       seed: int = 20261128) -> EffectUncertainty:
    """The uncertainty of ``jf``'s last effect, fitted jointly with the baseline (module docstring).

    :raises ModelError: if a simulation fails.
    """
    train = closer.train
    if len(train) > windows.WARM_START_SAMPLES:
        train = train.take(windows.window_index(train))
        closer = InModelCloser(closer.dyn, train, closer.test)
    eff, shape, coef = jf.effects[-1]
    free_idx = np.flatnonzero(closer.free)
    base_names = list(closer.dyn.params)
    keys = _numeric_shape(shape)
    names = ([f"base:{base_names[i]}" for i in free_idx] + [f"coef:{c}" for c in eff.coef_names]
             + [f"shape:{k}" for k in keys])
    theta = np.concatenate([jf.base[free_idx], np.asarray(coef, float), [float(shape[k]) for k in keys]])
    lo = np.concatenate([closer.lo, np.asarray(eff.lo, float), np.full(len(keys), -np.inf)])
    hi = np.concatenate([closer.hi, np.asarray(eff.hi, float), np.full(len(keys), np.inf)])
    nb, nc = free_idx.size, len(eff.coef_names)
    dt = float(np.median(np.diff(train.t_s))) if len(train) > 1 else 1e-3

    def model(x: np.ndarray) -> JointFit:
        base = jf.base.copy()
        base[free_idx] = x[:nb]
        sh = dict(shape)
        sh.update({k: float(v) for k, v in zip(keys, x[nb + nc:])})
        return JointFit(base, list(jf.effects[:-1]) + [(eff, sh, x[nb:nb + nc])])

    pred0 = closer.predict(model(theta), test=False)
    r = pred0 - closer.y
    J = np.empty((len(r), theta.size))
    for j in range(theta.size):
        if j >= nb + nc:
            key = keys[j - nb - nc]
            h = dt if key == "lag_s" else SHAPE_REL_STEP * max(abs(theta[j]), dt)
            if key == "lag_s":
                # whole samples both ways: the lag acts by shifting the prediction
                xp, xm = theta.copy(), theta.copy()
                xp[j] += h
                xm[j] -= h
                J[:, j] = (closer.predict(model(xp), test=False) - closer.predict(model(xm), test=False)) / (2 * h)
                continue
        else:
            h = REL_STEP * max(abs(theta[j]), 0.1 if j >= nb else 1e-3)
        if theta[j] + h > hi[j]:
            h = -h
        x = theta.copy()
        x[j] += h
        J[:, j] = (closer.predict(model(x), test=False) - pred0) / h
    labels = test_blocks(train, BLOCK_S)
    Ainv, G, cov = sandwich(J, r, labels)
    rng = np.random.default_rng(seed)
    counts = rng.multinomial(G.shape[0], np.full(G.shape[0], 1.0 / G.shape[0]), size=n_boot)
    boot = theta[None, :] - (counts @ G) @ Ainv.T
    # the "no effect" test: the shape held (its columns left out), the baseline free
    test_cols = list(range(nb, nb + nc)) if nc else [names.index("shape:lag_s")] if "lag_s" in keys else []
    keep = list(range(nb + nc)) if nc else list(range(nb)) + test_cols
    _, _, cov_h = sandwich(J[:, keep], r, labels)
    pos = [keep.index(c) for c in test_cols]
    C = cov_h[np.ix_(pos, pos)]
    c = theta[test_cols]
    wald = float(c @ np.linalg.pinv(C) @ c) if c.size else math.inf
    dof = max(len(test_cols), 1)
    return EffectUncertainty(names, theta, cov, boot, wald, dof, float(chi2.sf(wald, dof)))


def named_uncertainty(jf: JointFit, unc: EffectUncertainty, names: list[str],
                      refs: Refs) -> tuple[dict[str, float], dict[str, list[float]]]:
    """(standard error, 95 % bootstrap interval) of each named parameter of ``jf``'s last effect
    (:func:`.candidates._named`, its numeric shape, its raw coefficients ``coef:<name>``), from the
    linearised block bootstrap (module docstring)."""
    eff, shape, _ = jf.effects[-1]
    keys = [k for k in shape if f"shape:{k}" in unc.names]
    i_fc = unc.names.index("base:tau_fc_Nm") if "base:tau_fc_Nm" in unc.names else None
    ic = [unc.names.index(f"coef:{c}") for c in eff.coef_names]
    draws: dict[str, list[float]] = {}
    for th in unc.boot:
        tau_fc = float(th[i_fc]) if i_fc is not None else float(jf.base[names.index("tau_fc_Nm")])
        sh = {**shape, **{k: float(th[unc.names.index(f"shape:{k}")]) for k in keys}}
        named = _named(eff, sh, th[ic], tau_fc, refs)
        named.update({k: sh[k] for k in keys})
        named.update({f"coef:{c}": float(th[j]) for c, j in zip(eff.coef_names, ic)})
        for k, v in named.items():
            if isinstance(v, float) and not isinstance(v, bool):
                draws.setdefault(k, []).append(v)
    se = {k: float(np.std(v)) for k, v in draws.items() if np.ptp(v) > 0.0}
    ci = {k: [float(np.quantile(draws[k], 0.025)), float(np.quantile(draws[k], 0.975))] for k in se}
    return se, ci


#: bootstrap draws an empirical curve's peak-to-peak interval is taken from
N_PTP_DRAWS = 200


def described_with_interval(closer: InModelCloser, jf: JointFit, unc: EffectUncertainty, names: list[str],
                            refs: Refs, sup: tuple[float, float] | None) -> dict | None:
    """The description of ``jf``'s last effect (an empirical curve) at its joint refit, with the
    95 % interval of its peak-to-peak over the support ``sup`` from ``N_PTP_DRAWS`` of the
    bootstrap draws (module docstring)."""
    eff, _, coef = jf.effects[-1]
    i_fc = names.index("tau_fc_Nm")
    tau_fc = float(jf.base[i_fc])
    d = closer.describe(eff, coef, tau_fc, refs.drive_scale_Nm, sup)
    if d is None:
        return None
    ic = [unc.names.index(f"coef:{c}") for c in eff.coef_names]
    j_fc = unc.names.index("base:tau_fc_Nm") if "base:tau_fc_Nm" in unc.names else None
    key = "peak_to_peak_gain" if "peak_to_peak_gain" in d else "peak_to_peak_Nm"
    ptp = []
    for th in unc.boot[:N_PTP_DRAWS]:
        db = closer.describe(eff, th[ic], float(th[j_fc]) if j_fc is not None else tau_fc, refs.drive_scale_Nm, sup)
        if db is not None:
            ptp.append(float(db[key]))
    if ptp:
        lo, hi = float(np.quantile(ptp, 0.025)), float(np.quantile(ptp, 0.975))
        d[key + "_interval"] = [lo, hi]
        d["text"] += f" (peak-to-peak 95 % interval {lo:.3g}-{hi:.3g}, block bootstrap over 0.5 s windows)"
    return d
