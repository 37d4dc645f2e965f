"""The closure on the dynamic baseline (:mod:`capstan.models.closure.dynamic_baseline`).

The baseline is simulated through every sample of every run; the closure's effects are
then fitted on the *dynamic* residual: the augmented model of the target is

    target = dynamic prediction + c + sum_k F_k theta_k

with the catalogue's bases ``F_k`` (and the empirical curves) on the runs' signals, and
the same greedy selection by held-out block bootstrap as before. Signals that are not
mechanisms (:mod:`capstan.models.closure.exclusion`) are never candidates.

A late channel needs no realignment here: the dynamic model is time-invariant, so a
target measured ``lag`` late (or a driving channel ``lag`` early, negative lags) is the
prediction shifted by ``lag``; ``sensor_latency`` is the basis
``shift(prediction, lag) - prediction`` on the lag grid (whole samples).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from capstan.models.closure.dynamic_baseline import DynamicFit, fit_dynamic
from capstan.models.closure.effects import EffectSpec, FeatureContext, Target, shift_within_runs
from capstan.models.closure.exclusion import excluded_signals
from capstan.models.closure.signals import Signals

#: lag grid of the latency candidate [ms] (both signs: target late / driving channel late)
LAGS_MS = (1, 2, 3, 5, 8, 12, 18, 25, 35, 50, 70, 100)


@dataclass
class DynamicSetup:
    """The dynamic baseline and what the closure needs of it.

    :ivar pred_train_Nm / pred_test_Nm: the target predicted on every sample [Nm].
    :ivar excluded: ``{signal: reason}`` of the signals that are not candidates.
    """

    fit: DynamicFit
    pred_train_Nm: np.ndarray
    pred_test_Nm: np.ndarray
    y_train_Nm: np.ndarray
    y_test_Nm: np.ndarray
    excluded: dict[str, str]

    def allowed(self, spec: EffectSpec) -> bool:
        """True if no signal ``spec`` depends on is excluded (and it needs no realignment)."""
        return not spec.realigns and not any(d in self.excluded for d in spec.depends_on)


def target_channel(sig: Signals, target: str) -> np.ndarray:
    """The measured channel ``target`` ("tau_in" / "tau_out") of ``sig`` [Nm]."""
    return sig.tau_in_Nm if target == "tau_in" else sig.tau_out_Nm


def setup(train: Signals, test: Signals) -> DynamicSetup:
    """Fit the dynamic baseline on every training sample and predict both sets.

    :raises ModelError: if the baseline cannot be fitted or simulated.
    """
    fit = fit_dynamic(train)
    tgt = fit.spec.target
    return DynamicSetup(fit, fit.predict(train), fit.predict(test), target_channel(train, tgt),
                        target_channel(test, tgt), excluded_signals(train, tgt, fit.spec.driving))


def _f_latency(sig: Signals, ctx: FeatureContext, sh: dict, preds: dict[int, np.ndarray], fit: DynamicFit) -> np.ndarray:
    pred = preds.get(id(sig))
    if pred is None:
        pred = fit.predict(sig)
    return (shift_within_runs(pred, sig, float(sh["lag_s"])) - pred)[:, None]


def latency_spec(ds: DynamicSetup, train: Signals, test: Signals) -> EffectSpec:
    """The ``sensor_latency`` candidate on the dynamic prediction (module docstring)."""
    tgt = ds.fit.spec.target
    drv = "+".join(ds.fit.spec.driving)
    grid = tuple({"channel": tgt if s > 0 else drv, "lag_s": s * m / 1000.0} for m in LAGS_MS for s in (1, -1))
    preds = {id(train): ds.pred_train_Nm, id(test): ds.pred_test_Nm}
    return EffectSpec("sensor_latency", ("latency",), "a measured channel arrives late relative to the others",
                      f"{tgt} measured lag late (lag > 0) or the driving channels late (lag < 0)", ("gain",), grid,
                      partial(_f_latency, preds=preds, fit=ds.fit), Target.TAU_OUT, loss_sign=1.0, full_rate=True)


def skill(rmse_Nm: float, std_Nm: float) -> float:
    """``1 - RMSE / std`` of the predicted channel (0: no better than its mean; 1: exact)."""
    return float(1.0 - rmse_Nm / std_Nm) if std_Nm > 0.0 else float("nan")
