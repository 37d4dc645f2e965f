"""Model closure: fit the baseline on training runs, predict held-out runs, trace the
residual to signals, try every catalogued effect (and the empirical fallbacks), and
select greedily the ones whose held-out improvement is significant.

Significance: the held-out data are cut into contiguous blocks (``BLOCK_S`` seconds,
never crossing a run); a block bootstrap (``N_BOOT`` resamples of blocks) of
``1 - sqrt(sum SSE_after / sum SSE_before)`` gives a one-sided 95 % lower bound. A
candidate is *significant* when that bound is > 0 and the point improvement is at
least ``MATERIAL`` (5 % lower held-out RMSE). Each round refits, on the training data,
the baseline's linear parameters together with every selected effect and the
candidate (the baseline's nonlinear shape alpha, eta_s stays fixed).

Catalogue first: when both catalogue and empirical candidates are significant, the
best catalogue effect is taken if it achieves at least ``PREFER_CATALOGUE`` of the best
empirical improvement; otherwise the empirical curve is taken and described (which
signal, friction-like or additive, trend or period) instead of forcing an effect.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from models.effects import EffectSpec, FeatureContext, Target, catalogue_for
from models.identification import BaselineFit, ModelKind, fit_baseline
from models.residual_trace import describe_curve, empirical_candidates, is_empirical
from models.signals import Signals

MATERIAL = 0.05
PREFER_CATALOGUE = 0.7
BLOCK_S = 2.0
N_BOOT = 400
MAX_ROUNDS = 4
RIDGE = 1e-4
MAX_SAMPLES = 20000

Progress = Callable[[int, int, str], None]


@dataclass
class Candidate:
    """One candidate tried in one round (see the module docstring for the scores)."""

    effect: str
    depends_on: list[str]
    target: Target
    round: int
    shape: dict
    params: dict[str, float]
    rmse_Nm: float
    max_err_Nm: float
    improvement: float
    ci_low: float
    significant: bool
    spec: EffectSpec | None = None
    F_train: np.ndarray | None = None
    F_test: np.ndarray | None = None
    description: dict | None = None

    def summary(self) -> dict:
        """JSON-able summary."""
        d = {"effect": self.effect, "depends_on": list(self.depends_on), "target": self.target.name.lower(),
             "round": self.round, "rmse_Nm": self.rmse_Nm, "max_err_Nm": self.max_err_Nm,
             "improvement": self.improvement, "improvement_ci_low": self.ci_low, "significant": self.significant}
        if self.description:
            d["description"] = self.description["text"]
        return d


@dataclass
class TargetResult:
    """Closure of one target (the friction path tau_out, or the elastic path)."""

    target: Target
    y_test: np.ndarray
    pred_before: np.ndarray
    pred_after: np.ndarray
    rmse_before_Nm: float
    max_before_Nm: float
    rmse_after_Nm: float
    max_after_Nm: float
    candidates: list[Candidate] = field(default_factory=list)
    selected: list[Candidate] = field(default_factory=list)
    theta: np.ndarray | None = None


@dataclass
class ClosureResult:
    """Everything the report needs."""

    baseline: BaselineFit
    train: Signals
    test: Signals
    targets: dict[Target, TargetResult]
    trace: list[dict]


def _rmse(r: np.ndarray) -> float:
    return float(np.sqrt(np.mean(r ** 2))) if r.size else math.nan


def test_blocks(sig: Signals, block_s: float = BLOCK_S) -> np.ndarray:
    """Block label per held-out sample: contiguous ~block_s pieces inside each run (>= 8 blocks)."""
    labels = np.empty(len(sig), dtype=np.int64)
    dt = float(np.median(np.diff(sig.t_s))) if len(sig) > 1 else 1e-3
    per = max(50, int(block_s / max(dt, 1e-6)))
    per = min(per, max(50, len(sig) // 8))
    k = 0
    for a, b in sig.segments():
        m = b - a
        nb = max(1, int(round(m / per)))
        labels[a:b] = k + np.minimum((np.arange(m) * nb) // m, nb - 1)
        k += nb
    return labels


def block_bootstrap(r_before: np.ndarray, r_after: np.ndarray, labels: np.ndarray,
                    n_boot: int = N_BOOT, seed: int = 12345) -> tuple[float, float]:
    """(point improvement, one-sided 95 % lower bound) of the relative RMSE reduction."""
    nb = int(labels.max()) + 1
    sb = np.bincount(labels, r_before ** 2, nb)
    sa = np.bincount(labels, r_after ** 2, nb)
    point = 1.0 - math.sqrt(sa.sum() / max(sb.sum(), 1e-300))
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, nb, size=(n_boot, nb))
    boots = 1.0 - np.sqrt(sa[idx].sum(axis=1) / np.maximum(sb[idx].sum(axis=1), 1e-300))
    return point, float(np.quantile(boots, 0.05))


def _scaled_lstsq(X: np.ndarray, y: np.ndarray, ridge_cols: np.ndarray) -> np.ndarray:
    """Least squares via the normal equations of the column-scaled problem.

    Columns flagged in ``ridge_cols`` (the empirical curves) get a ridge of
    ``RIDGE * n``; every column gets a 1e-10 relative ridge for rank-deficient cases.
    """
    scale = np.maximum(np.sqrt((X ** 2).mean(axis=0)), 1e-12)
    Xs = X / scale
    G = Xs.T @ Xs
    n = X.shape[0]
    G[np.diag_indices_from(G)] += 1e-10 * n + RIDGE * n * ridge_cols
    try:
        sol = np.linalg.solve(G, Xs.T @ y)
    except np.linalg.LinAlgError:
        sol = np.linalg.pinv(G) @ (Xs.T @ y)
    return sol / scale


def _target_data(t: Target, sig: Signals, baseline: BaselineFit) -> tuple[np.ndarray, np.ndarray]:
    if t == Target.TAU_OUT:
        return baseline.basis(sig), sig.tau_out_Nm
    assert sig.q_in_rad is not None
    return np.column_stack([sig.q_in_rad, sig.q_out_rad, np.ones(len(sig))]), sig.tau_in_Nm + sig.tau_out_Nm


def _close_target(t: Target, specs: list[EffectSpec], train: Signals, test: Signals, idx_tr: np.ndarray,
                  idx_te: np.ndarray, ctx: FeatureContext, labels: np.ndarray, progress: Progress | None,
                  step0: int, total: int) -> tuple[TargetResult, int]:
    """Greedy closure of one target. Features are computed on the full-rate signals
    (time shifts stay exact) and fitted on the decimated rows ``idx_tr`` / ``idx_te``."""
    train_d, test_d = train.take(idx_tr), test.take(idx_te)
    X0, y = _target_data(t, train_d, ctx.baseline)
    X0t, yt = _target_data(t, test_d, ctx.baseline)
    blocks_tr: list[np.ndarray] = [X0]
    blocks_te: list[np.ndarray] = [X0t]
    ridge: list[np.ndarray] = [np.zeros(X0.shape[1], bool)]
    fixed_tr, fixed_te = np.zeros(len(y)), np.zeros(len(yt))
    theta = _scaled_lstsq(X0, y, ridge[0])
    pred_t = X0t @ theta
    before = pred_t.copy()
    res = TargetResult(t, yt, before, pred_t, _rmse(yt - pred_t), float(np.max(np.abs(yt - pred_t))),
                       math.nan, math.nan)
    remaining = list(specs)
    step = step0
    for rnd in range(1, MAX_ROUNDS + 1):
        Xc = np.hstack(blocks_tr)
        Q, _ = np.linalg.qr(Xc / np.maximum(np.sqrt((Xc ** 2).mean(axis=0)), 1e-12))
        r0 = (y - fixed_tr) - Q @ (Q.T @ (y - fixed_tr))
        r_before = yt - pred_t
        tried: list[Candidate] = []
        for spec in remaining:
            step += 1
            if progress:
                progress(step, total, f"round {rnd}: {spec.name}")
            best = (math.inf, None, None)
            for shape in spec.grid:
                F = spec.features(train, ctx, shape)[idx_tr] if spec.full_rate else spec.features(train_d, ctx, shape)
                Ft = F - Q @ (Q.T @ F)
                if spec.fixed_gain:      # enters with coefficient 1, nothing to fit
                    sse = float(np.sum((r0 - Ft.sum(axis=1)) ** 2))
                else:
                    c = _scaled_lstsq(Ft, r0, np.full(Ft.shape[1], is_empirical(spec)))
                    sse = float(np.sum((r0 - Ft @ c) ** 2))
                if sse < best[0]:
                    best = (sse, shape, F)
            _, shape, F = best
            if F is None:
                continue
            Fte = spec.features(test, ctx, shape)[idx_te] if spec.full_rate else spec.features(test_d, ctx, shape)
            if spec.fixed_gain:
                F, Fte = F.sum(axis=1, keepdims=True), Fte.sum(axis=1, keepdims=True)
                th = _scaled_lstsq(np.hstack(blocks_tr), y - fixed_tr - F[:, 0], np.concatenate(ridge))
                p_after = np.hstack(blocks_te) @ th + fixed_te + Fte[:, 0]
                coef = np.zeros(0)
            else:
                rc = np.concatenate(ridge + [np.full(F.shape[1], is_empirical(spec))])
                th = _scaled_lstsq(np.hstack(blocks_tr + [F]), y - fixed_tr, rc)
                p_after = np.hstack(blocks_te + [Fte]) @ th + fixed_te
                coef = th[-F.shape[1]:] * spec.loss_sign
            r_after = yt - p_after
            imp, lo = block_bootstrap(r_before, r_after, labels)
            cand = Candidate(spec.name, list(spec.depends_on), t, rnd,
                             {k: v for k, v in shape.items() if k != "knots"},
                             {n: float(c) for n, c in zip(spec.coef_names, coef)} if not is_empirical(spec) else {},
                             _rmse(r_after), float(np.max(np.abs(r_after))), imp, lo,
                             bool(lo > 0.0 and imp >= MATERIAL), spec, F, Fte)
            if is_empirical(spec):
                knots = np.array([float(k) for k in str(shape["knots"]).split(",")])
                cand.description = describe_curve(spec.depends_on[0], knots, th[-F.shape[1]:])
                cand.description["knots"] = knots.tolist()
                cand.description["curve"] = th[-F.shape[1]:].tolist()
            tried.append(cand)
        res.candidates.extend(tried)
        sig_c = [c for c in tried if c.significant]
        if not sig_c:
            break
        cat = [c for c in sig_c if not is_empirical(c.spec)]
        emp = [c for c in sig_c if is_empirical(c.spec)]
        best_cat = max(cat, key=lambda c: c.improvement) if cat else None
        best_emp = max(emp, key=lambda c: c.improvement) if emp else None
        if best_cat is not None and (best_emp is None or best_cat.improvement >= PREFER_CATALOGUE * best_emp.improvement):
            win = best_cat
        else:
            win = best_emp
        assert win is not None and win.F_train is not None and win.F_test is not None and win.spec is not None
        res.selected.append(win)
        if win.spec.fixed_gain:
            fixed_tr = fixed_tr + win.F_train[:, 0]
            fixed_te = fixed_te + win.F_test[:, 0]
        else:
            blocks_tr.append(win.F_train)
            blocks_te.append(win.F_test)
            ridge.append(np.full(win.F_train.shape[1], is_empirical(win.spec)))
        theta = _scaled_lstsq(np.hstack(blocks_tr), y - fixed_tr, np.concatenate(ridge))
        pred_t = np.hstack(blocks_te) @ theta + fixed_te
        remaining = [s for s in remaining if s.name != win.effect or s.depends_on != tuple(win.depends_on)]
        for c in tried:      # free memory of the losers
            if c is not win:
                c.F_train = c.F_test = None
    res.pred_after = pred_t
    res.theta = theta
    res.rmse_after_Nm = _rmse(yt - pred_t)
    res.max_after_Nm = float(np.max(np.abs(yt - pred_t)))
    return res, step


def decimation_index(n: int, max_samples: int | None) -> np.ndarray:
    """Indices of every k-th sample so that at most ``max_samples`` remain (no averaging:
    the noise the friction law sees stays that of the sensor)."""
    k = max(1, int(math.ceil(n / max_samples))) if max_samples else 1
    return np.arange(0, n, k)


def close(train: Signals, test: Signals, kind: ModelKind = ModelKind.REDUCED,
          progress: Progress | None = None, max_samples: int | None = MAX_SAMPLES) -> ClosureResult:
    """Run the closure (see module docstring).

    Signals are derived at the full rate by the caller; the fits use at most
    ``max_samples`` samples of each of train and test (every k-th sample).

    :raises ModelError: if the baseline cannot be fitted.
    """
    idx_tr, idx_te = decimation_index(len(train), max_samples), decimation_index(len(test), max_samples)
    train_d, test_d = train.take(idx_tr), test.take(idx_te)
    baseline = fit_baseline(train_d, kind)
    ctx = FeatureContext.from_train(train_d, baseline)
    labels = test_blocks(test_d)
    emp = empirical_candidates(train)
    specs = {Target.TAU_OUT: [s for s in catalogue_for(train) + emp if s.target == Target.TAU_OUT and s.applicable(test)]}
    if train.deflection_rad is not None and test.deflection_rad is not None:
        specs[Target.ELASTIC] = [s for s in catalogue_for(train) + emp if s.target == Target.ELASTIC]
    total = sum(len(v) for v in specs.values()) * 2
    targets: dict[Target, TargetResult] = {}
    step = 0
    for t, sp in specs.items():
        targets[t], step = _close_target(t, sp, train, test, idx_tr, idx_te, ctx, labels, progress, step, total)
    trace = []
    for c in targets[Target.TAU_OUT].candidates:
        if c.round == 1 and (is_empirical(c.spec) or c.effect == "sensor_latency"):
            trace.append({"signal": c.depends_on[0], "explained": max(0.0, 1.0 - (1.0 - c.improvement) ** 2),
                          "improvement": c.improvement, "significant": c.significant})
    trace.sort(key=lambda d: -d["explained"])
    if progress:
        progress(total, total, "done")
    return ClosureResult(baseline, train_d, test_d, targets, trace)


def split_single(sig: Signals, train_fraction: float = 0.7) -> tuple[Signals, Signals]:
    """Split one run into a contiguous training head and a held-out tail (never random samples)."""
    n = len(sig)
    k = int(round(train_fraction * n))
    idx = np.arange(n)
    return sig.take(idx < k), sig.take(idx >= k)
