"""The augmented model of one closure target: the baseline (its shape and, once a
sensor latency is selected, the late channel realigned) plus the selected effects.

A late channel is realigned on the full-rate signals, whole samples inside each run: a
late velocity (and everything derived from it: acceleration, dwell states) is advanced
by the lag; a late output torque is matched by delaying every other channel. The whole
model -- the baseline and every effect's basis -- is then evaluated on the realigned
signals, as the physics requires: evaluating only part of it on the realigned channel
would let the model average two looks at the same noisy signal and call that an effect.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from capstan.models.closure.baseline_shape import ModelKind, ShapeProblem, design, fit_shape
from capstan.models.closure.effects import EffectSpec, FeatureContext, Target, shift_within_runs
from capstan.models.common.errors import ModelError
from capstan.models.closure.signals import Signals

#: ridge of the empirical curves' columns, relative to the number of samples
RIDGE = 1e-4
#: signal fields derived from the velocity (they arrive as late as it does)
_FROM_VELOCITY = ("dq_out_rad_s", "ddq_out_rad_s2", "dwell_s", "rest_s", "slide_rad")
#: every measured or derived field except the clock, run label and output torque
_ALL_INPUTS = _FROM_VELOCITY + ("tau_in_Nm", "q_out_rad", "q_in_rad", "tension_N")


def scaled_lstsq(X: np.ndarray, y: np.ndarray, ridge_cols: np.ndarray) -> np.ndarray:
    """Least squares via the normal equations of the column-scaled problem.

    Columns flagged in ``ridge_cols`` (the empirical curves) get a ridge of
    ``RIDGE * n``; every column gets a 1e-10 relative ridge for rank-deficient cases.
    """
    scale = np.maximum(np.sqrt((X ** 2).mean(axis=0)), 1e-12)
    Xs = X / scale
    G = Xs.T @ Xs
    n = X.shape[0]
    G[np.diag_indices_from(G)] += 1e-10 * n + RIDGE * n * ridge_cols
    b = np.einsum("ij,i->j", Xs, y)
    try:
        sol = np.linalg.solve(G, b)
    except np.linalg.LinAlgError:
        sol = np.linalg.pinv(G) @ b
    return sol / scale


@dataclass(frozen=True)
class Realign:
    """A measured channel that arrives late: ``channel`` is ``"dq_out"`` (the velocity
    the friction law is evaluated on) or ``"tau_out"`` (the measured output torque);
    ``lag_s`` [s] is its delay (negative: early)."""

    channel: str
    lag_s: float

    def __post_init__(self) -> None:
        if self.channel not in ("dq_out", "tau_out"):
            raise ModelError(f"cannot realign channel {self.channel!r}; one of dq_out, tau_out")

    def as_shape(self) -> dict[str, float | str]:
        """``{"channel", "lag_s"}`` as the latency candidate's shape."""
        return {"channel": self.channel, "lag_s": float(self.lag_s)}

    def shift_s(self) -> float:
        """The delay applied to the realigned fields [s] (negative: advanced)."""
        return -self.lag_s if self.channel == "dq_out" else self.lag_s


def realigned_inputs(sig: Signals, realign: Realign | None) -> tuple[np.ndarray, np.ndarray]:
    """(tau_in [Nm], dq_out [rad/s]) of ``sig`` with ``realign`` applied (see module docstring)."""
    if realign is None or realign.lag_s == 0.0:
        return sig.tau_in_Nm, sig.dq_out_rad_s
    sh = realign.shift_s()
    tin = sig.tau_in_Nm if realign.channel == "dq_out" else shift_within_runs(sig.tau_in_Nm, sig, sh)
    return tin, shift_within_runs(sig.dq_out_rad_s, sig, sh)


def realigned_signals(sig: Signals, realign: Realign | None) -> Signals:
    """``sig`` with ``realign`` applied to every affected field (see module docstring)."""
    if realign is None or realign.lag_s == 0.0:
        return sig
    sh = realign.shift_s()
    names = _FROM_VELOCITY if realign.channel == "dq_out" else _ALL_INPUTS
    new: dict[str, object] = {}
    for name in names:
        x = getattr(sig, name)
        if x is not None:
            new[name] = shift_within_runs(x, sig, sh)
    if realign.channel == "tau_out":
        new["extras"] = {k: shift_within_runs(x, sig, sh) for k, x in sig.extras.items()}
    return dataclasses.replace(sig, **new)


def argmin_int(f: Callable[[int], float], lo: int, hi: int) -> int:
    """The integer in [lo, hi] minimising ``f`` by golden-section search (``f`` assumed
    unimodal there), each value evaluated once."""
    seen: dict[int, float] = {}

    def F(m: int) -> float:
        if m not in seen:
            seen[m] = f(m)
        return seen[m]

    a, b = lo, hi
    while b - a > 3:
        m1 = a + int(round(0.382 * (b - a)))
        m2 = max(m1 + 1, a + int(round(0.618 * (b - a))))
        if F(m1) <= F(m2):
            b = m2
        else:
            a = m1
    return min(range(a, b + 1), key=F)


@dataclass
class TargetData:
    """One target's data: the full-rate runs (time shifts stay exact), the decimated rows
    the fits use, the target on those rows, and a fixed linear design where the model is
    linear (the elastic path's [q_in, q_out, 1]; the dynamic residual's [1]), else None
    (the static friction path: its shape is refitted)."""

    target: Target
    kind: ModelKind
    train: Signals
    test: Signals
    idx_tr: np.ndarray
    idx_te: np.ndarray
    y_Nm: np.ndarray
    yt_Nm: np.ndarray
    X0: np.ndarray | None
    X0t: np.ndarray | None
    v95_rad_s: float

    def inputs(self, realign: Realign | None, test: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(tau_in, dq_out) on the decimated rows, realigned at full rate."""
        sig, idx = (self.test, self.idx_te) if test else (self.train, self.idx_tr)
        tin, v = realigned_inputs(sig, realign)
        return tin[idx], v[idx]


@dataclass
class AugmentedFit:
    """One refit of the augmented model: parameters, shape and held-out prediction [Nm]."""

    theta: np.ndarray
    pred_test_Nm: np.ndarray
    alpha_s_rad: float
    eta_s_rad_s: float


@dataclass
class Augmented:
    """The augmented model of one target after the closure's rounds so far."""

    data: TargetData
    ctx: FeatureContext
    alpha_s_rad: float
    eta_s_rad_s: float
    realign: Realign | None = None
    #: selected effects with a basis: (spec, shape, ridge flags of its columns)
    selected: list[tuple[EffectSpec, dict, np.ndarray]] = field(default_factory=list)
    #: the current parameters (baseline's, then the selected bases' in order), once refitted
    theta: np.ndarray | None = None
    _sigs: dict = field(default_factory=dict, repr=False)

    def _signals(self, realign: Realign | None, test: bool) -> tuple[Signals, Signals]:
        key = (realign, test)
        if key not in self._sigs:
            if len(self._sigs) >= 4:
                self._sigs.clear()
            d = self.data
            full = realigned_signals(d.test if test else d.train, realign)
            self._sigs[key] = (full, full.take(d.idx_te if test else d.idx_tr))
        return self._sigs[key]

    def features(self, spec: EffectSpec, shape: dict, realign: Realign | None, test: bool = False) -> np.ndarray:
        """``spec``'s basis on the decimated rows of the realigned signals."""
        full, dec = self._signals(realign, test)
        idx = self.data.idx_te if test else self.data.idx_tr
        return spec.features(full, self.ctx, shape)[idx] if spec.full_rate else spec.features(dec, self.ctx, shape)

    def extra(self, realign: Realign | None, F: np.ndarray | None = None, test: bool = False) -> np.ndarray:
        """The selected effects' bases (and a candidate's ``F``) on the training or held-out rows."""
        n = (self.data.idx_te if test else self.data.idx_tr).shape[0]
        cols = [self.features(s, sh, realign, test) for s, sh, _ in self.selected] + ([F] if F is not None else [])
        return np.hstack(cols) if cols else np.zeros((n, 0))

    def ridge_cols(self, ridge_F: np.ndarray | None = None) -> np.ndarray:
        """Ridge flags of the columns of :meth:`extra`."""
        parts = [r for _, _, r in self.selected] + ([ridge_F] if ridge_F is not None else [])
        return np.concatenate(parts + [np.zeros(0, bool)])

    def _design(self, realign: Realign | None, test: bool, alpha: float, eta: float,
                F: np.ndarray | None = None) -> np.ndarray:
        d = self.data
        ex = self.extra(realign, F, test)
        if d.X0 is not None:      # a fixed linear design (elastic path, dynamic residual)
            X0 = d.X0t if test else d.X0
            assert X0 is not None
            return np.hstack([X0, ex])
        return design(d.kind, *d.inputs(realign, test), alpha, eta, ex)

    def design_train(self) -> np.ndarray:
        """Training design of the current model at its current shape."""
        return self._design(self.realign, False, self.alpha_s_rad, self.eta_s_rad_s)

    def design_test(self) -> np.ndarray:
        """Held-out design of the current model at its current shape."""
        return self._design(self.realign, True, self.alpha_s_rad, self.eta_s_rad_s)

    def fit(self, F_tr: np.ndarray | None, F_te: np.ndarray | None, ridge_F: np.ndarray | None,
            realign: Realign | None) -> AugmentedFit:
        """Refit on the training rows with a candidate basis ``F`` and/or realignment.

        The friction path refits the baseline's shape too
        (:func:`capstan.models.closure.baseline_shape.fit_shape`); the elastic path is linear.
        """
        d = self.data
        rid = self.ridge_cols(ridge_F)
        if d.X0 is not None:
            X = self._design(None, False, math.nan, math.nan, F_tr)
            th = scaled_lstsq(X, d.y_Nm, np.concatenate([np.zeros(X.shape[1] - rid.size, bool), rid]))
            return AugmentedFit(th, self._design(None, True, math.nan, math.nan, F_te) @ th, math.nan, math.nan)
        tin, v = d.inputs(realign)
        prob = ShapeProblem(d.kind, tin, v, d.y_Nm, self.extra(realign, F_tr), rid, RIDGE)
        fit = fit_shape(prob, d.v95_rad_s, (self.alpha_s_rad, self.eta_s_rad_s))
        pred = self._design(realign, True, fit.alpha_s_rad, fit.eta_s_rad_s, F_te) @ fit.theta
        return AugmentedFit(fit.theta, pred, fit.alpha_s_rad, fit.eta_s_rad_s)

    def best_lag(self, grid: tuple[dict[str, float | str], ...], rows: np.ndarray | None = None) -> Realign:
        """The late channel and its lag: the (channel, lag_s) of ``grid`` with the lowest
        training SSE at the current shape, then the lag refined as a free parameter at the
        sampling resolution (golden-section search over the whole samples between its
        neighbouring grid lags) with the baseline's shape refitted for each lag (a late
        velocity also bends the shape). The selected effects are held at their current
        contributions during the search; the candidate is then scored with everything
        refitted jointly.

        ``rows``: the training rows to search on (default: the fitting rows). A lag search
        wants consecutive samples: on every k-th sample, which noise samples a shift of
        one sample pairs up changes with the shift and biases the lag by a sample.
        """
        if rows is not None:
            sub = dataclasses.replace(self.data, idx_tr=rows, y_Nm=self.data.train.tau_out_Nm[rows])
            return dataclasses.replace(self, data=sub, selected=list(self.selected), _sigs={}).best_lag(grid)
        d = self.data
        ex0 = self.extra(self.realign)
        y = d.y_Nm - ex0 @ self.theta[5:] if ex0.shape[1] and self.theta is not None else d.y_Nm

        def sse_fixed(r: Realign) -> float:
            X = design(d.kind, *d.inputs(r), self.alpha_s_rad, self.eta_s_rad_s)
            res = y - X @ scaled_lstsq(X, y, np.zeros(X.shape[1], bool))
            return float(np.einsum("i,i->", res, res))

        scored = [(sse_fixed(Realign(str(sh["channel"]), float(sh["lag_s"]))), str(sh["channel"]), float(sh["lag_s"]))
                  for sh in grid]
        _, ch, lag = min(scored, key=lambda x: x[0])
        mags = sorted({abs(float(sh["lag_s"])) for sh in grid})
        dt = float(np.median(np.diff(d.train.t_s))) if len(d.train) > 1 else 1e-3
        k = mags.index(abs(lag))
        lo = int(round(mags[k - 1] / dt)) + 1 if k > 0 else 1
        hi = int(round(mags[k + 1] / dt)) - 1 if k + 1 < len(mags) else int(round(abs(lag) / dt))
        sign = 1.0 if lag > 0 else -1.0

        def sse_refit(m: int) -> float:
            tin, v = d.inputs(Realign(ch, sign * round(m * dt, 9)))
            return fit_shape(ShapeProblem(d.kind, tin, v, y), d.v95_rad_s, (self.alpha_s_rad, self.eta_s_rad_s)).sse

        m = argmin_int(sse_refit, lo, max(lo, hi))
        return Realign(ch, sign * round(m * dt, 9))

    def add(self, spec: EffectSpec, shape: dict, ridge_F: np.ndarray | None, realign: Realign | None,
            fit: AugmentedFit) -> None:
        """Take a selected candidate into the model (its basis, realignment, refitted shape
        and parameters)."""
        if ridge_F is not None and ridge_F.size:
            self.selected.append((spec, shape, ridge_F))
        self.realign = realign
        self.theta = fit.theta
        if math.isfinite(fit.alpha_s_rad):
            self.alpha_s_rad, self.eta_s_rad_s = fit.alpha_s_rad, fit.eta_s_rad_s
