"""Model closure: fit the baseline on training runs, predict held-out runs, trace the
residual to signals, try every catalogued effect (and the empirical fallbacks), and
select greedily the ones whose held-out improvement is significant.

Significance: the held-out data are cut into contiguous blocks (``BLOCK_S`` seconds,
never crossing a run); a block bootstrap (``N_BOOT`` resamples of blocks) of
``1 - sqrt(sum SSE_after / sum SSE_before)`` gives a one-sided 95 % lower bound. A
candidate is *significant* when that bound is > 0 and the point improvement is at
least ``MATERIAL`` (5 % lower held-out RMSE).

Each candidate is scored as an augmented model refitted on the training data: the
baseline's parameters -- linear ones *and* its nonlinear shape alpha, eta_s
(:mod:`capstan.models.closure.baseline_shape`) -- jointly with every selected effect and the candidate. A
baseline fitted alone bends its viscous term and Stribeck shape to absorb what it lacks;
only the joint refit gives an overlapping candidate (drag at speed) its full share. A
latency candidate realigns the late channel (lag on a grid, refined to whole samples
on consecutive training samples) and the whole model is re-evaluated on the realigned
signals (:mod:`capstan.models.closure.augmented`).

Catalogue first: when both catalogue and empirical candidates are significant, the
best catalogue effect is taken if it achieves at least ``PREFER_CATALOGUE`` of the best
empirical improvement; otherwise the empirical curve is taken and described (which
signal, friction-like or additive, trend or period) instead of forcing an effect.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from capstan.models.closure.dynamic.closure import DynamicSetup, close_in_model
from capstan.models.closure.dynamic.closure import setup as dyn_setup
from capstan.models.closure.augmented import Augmented, AugmentedFit, Realign, TargetData, scaled_lstsq
from capstan.models.closure.effects import EffectSpec, FeatureContext, Target, catalogue_for
from capstan.models.closure.identification import BaselineFit, ModelKind, fit_baseline, named_params
from capstan.models.closure.residual_trace import describe_curve, empirical_candidates, is_empirical
from capstan.models.closure.scoring import (BLOCK_S, MATERIAL, N_BOOT, PREFER_CATALOGUE, Candidate,  # noqa: F401
                                            TargetResult, _rmse, block_bootstrap, select_winner, test_blocks)
from capstan.models.closure.shape_words import support
from capstan.models.closure.signals import Signals

MAX_ROUNDS = 4
MAX_SAMPLES = 20000
#: at most this many consecutive training samples for the latency search
LAG_MAX_SAMPLES = 100000

Progress = Callable[[int, int, str], None]


@dataclass
class ClosureResult:
    """Everything the report needs."""

    baseline: BaselineFit
    train: Signals
    test: Signals
    targets: dict[Target, TargetResult]
    trace: list[dict]
    #: the dynamic baseline (None: the static regression predicted tau_out)
    dynamic: DynamicSetup | None = None
    #: wall time of the closure's stages [s] (feedforward, baseline, trace, candidates)
    timings_s: dict[str, float] = field(default_factory=dict)


def _best_shape(spec: EffectSpec, aug: Augmented, Q: np.ndarray,
                r0: np.ndarray) -> tuple[dict | None, np.ndarray | None]:
    """The shape of ``spec``'s grid whose basis best explains the training residual ``r0``
    of the current model (projected out: ``Q`` spans its design), with its basis."""
    best: tuple[float, dict | None, np.ndarray | None] = (math.inf, None, None)
    for sh in spec.grid:
        F = aug.features(spec, sh, aug.realign)
        Ft = F - Q @ (Q.T @ F)
        c = scaled_lstsq(Ft, r0, np.full(Ft.shape[1], is_empirical(spec)))
        sse = float(np.sum((r0 - Ft @ c) ** 2))
        if sse < best[0]:
            best = (sse, sh, F)
    return best[1], best[2]


def _close_target(aug: Augmented, specs: list[EffectSpec], labels: np.ndarray,
                  progress: Progress | None, step0: int, total: int) -> tuple[TargetResult, int]:
    """Greedy closure of one target. Features are computed on the full-rate signals
    (time shifts stay exact) and fitted on the decimated rows."""
    d = aug.data
    if aug.theta is None:      # a linear path (elastic, dynamic residual): its linear fit
        X0 = aug.design_train()
        aug.theta = scaled_lstsq(X0, d.y_Nm, np.zeros(X0.shape[1], bool))
    theta = aug.theta
    pred_t = aug.design_test() @ theta
    yt = d.yt_Nm
    res = TargetResult(d.target, yt, pred_t.copy(), pred_t, _rmse(yt - pred_t), float(np.max(np.abs(yt - pred_t))),
                       math.nan, math.nan)
    static = d.target == Target.TAU_OUT and d.X0 is None
    if static:
        res.params_after = named_params(d.kind, theta, aug.alpha_s_rad, aug.eta_s_rad_s)
    remaining = list(specs)
    step = step0
    for rnd in range(1, MAX_ROUNDS + 1):
        Xc = aug.design_train()
        Q, _ = np.linalg.qr(Xc / np.maximum(np.sqrt((Xc ** 2).mean(axis=0)), 1e-12))
        r0 = d.y_Nm - Q @ (Q.T @ d.y_Nm)
        r_before = yt - pred_t
        tried: list[Candidate] = []
        fits: dict[int, tuple[AugmentedFit, Realign | None, np.ndarray | None, dict]] = {}
        for spec in remaining:
            step += 1
            if progress:
                progress(step, total, f"round {rnd}: {spec.name}")
            realign = aug.realign
            F: np.ndarray | None = None
            Fte: np.ndarray | None = None
            ridge_F: np.ndarray | None = None
            if spec.realigns:
                if not static or aug.realign is not None:
                    continue
                realign = aug.best_lag(spec.grid, decimation_index(len(d.train), LAG_MAX_SAMPLES))
                shape: dict = realign.as_shape()
            else:
                sh, F = _best_shape(spec, aug, Q, r0)
                if sh is None or F is None:
                    continue
                shape = sh
                Fte = aug.features(spec, shape, realign, test=True)
                ridge_F = np.full(F.shape[1], is_empirical(spec))
            fit = aug.fit(F, Fte, ridge_F, realign)
            th = fit.theta
            k = 0 if F is None else F.shape[1]
            coef = th[len(th) - k:] * spec.loss_sign
            r_after = yt - fit.pred_test_Nm
            imp, lo = block_bootstrap(r_before, r_after, labels)
            cand = Candidate(spec.name, list(spec.depends_on), d.target, rnd,
                             {key: v for key, v in shape.items() if key != "knots"},
                             {n: float(c) for n, c in zip(spec.coef_names, coef)} if not is_empirical(spec) else {},
                             _rmse(r_after), float(np.max(np.abs(r_after))), imp, lo,
                             bool(lo > 0.0 and imp >= MATERIAL), spec, F, Fte)
            if static:
                cand.baseline_params = named_params(d.kind, th, fit.alpha_s_rad, fit.eta_s_rad_s)
            if is_empirical(spec) and k:
                knots = np.array([float(x) for x in str(shape["knots"]).split(",")])
                x_sig = d.train.signal(spec.depends_on[0])
                cand.description = describe_curve(spec.depends_on[0], knots, th[len(th) - k:],
                                                  sup=support(x_sig) if x_sig is not None else None)
                cand.description["knots"] = knots.tolist()
                cand.description["curve"] = th[len(th) - k:].tolist()
            fits[id(cand)] = (fit, realign, ridge_F, shape)
            tried.append(cand)
        res.candidates.extend(tried)
        sig_c = [c for c in tried if c.significant]
        if not sig_c:
            break
        win = select_winner(sig_c, lambda c: is_empirical(c.spec))
        res.selected.append(win)
        wfit, wrealign, wridge, wshape = fits[id(win)]
        assert win.spec is not None
        aug.add(win.spec, wshape, wridge, wrealign, wfit)
        if win.baseline_params is not None:
            res.params_after = win.baseline_params
        pred_t, theta = wfit.pred_test_Nm, wfit.theta
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
          progress: Progress | None = None, max_samples: int | None = MAX_SAMPLES,
          dynamic: bool = True) -> ClosureResult:
    """Run the closure (see module docstring).

    ``dynamic`` (default): the baseline is the reduced model simulated through every
    sample of every run (:mod:`capstan.models.closure.dynamic.closure`), the effects are
    fitted on its residual, and signals tied to the predicted channel are excluded;
    otherwise the static friction-on-velocity regression of tau_out. The static
    regression is fitted in both cases: it is the controller's feedforward map.

    Signals are derived at the full rate by the caller; the effect fits use at most
    ``max_samples`` samples of each of train and test (every k-th sample).

    :raises ModelError: if a baseline cannot be fitted.
    """
    t0 = time.perf_counter()
    idx_tr, idx_te = decimation_index(len(train), max_samples), decimation_index(len(test), max_samples)
    train_d, test_d = train.take(idx_tr), test.take(idx_te)
    baseline = fit_baseline(train_d, kind)
    ctx = FeatureContext.from_train(train_d, baseline)
    labels = test_blocks(test_d)
    emp = empirical_candidates(train)
    t1 = time.perf_counter()
    timings = {"feedforward": t1 - t0}
    ds = dyn_setup(train, test) if dynamic else None
    timings["baseline"] = time.perf_counter() - t1
    specs = {Target.TAU_OUT: [s for s in catalogue_for(train) + emp
                              if s.target == Target.TAU_OUT and s.applicable(test)] if ds is None else []}
    # the static elastic path (tau_in + tau_out linear in the angles) only beside the static
    # baseline: the dynamic model carries the elastic state itself
    if ds is None and train.deflection_rad is not None and test.deflection_rad is not None:
        specs[Target.ELASTIC] = [s for s in catalogue_for(train) + emp if s.target == Target.ELASTIC]
    total = sum(len(v) for v in specs.values()) * 2
    v95 = float(np.percentile(np.abs(train_d.dq_out_rad_s), 95))
    targets: dict[Target, TargetResult] = {}
    step = 0
    for t, sp in specs.items():
        X0: np.ndarray | None = None
        X0t: np.ndarray | None = None
        theta0: np.ndarray | None = None
        if t == Target.TAU_OUT and ds is not None:     # effects inside the simulation
            t2 = time.perf_counter()
            r, step = close_in_model(ds, train, test, progress, step, total)
            timings["trace"] = ds.timings_s.get("trace", 0.0)
            timings["candidates"] = time.perf_counter() - t2 - timings["trace"]
            # scored on every held-out sample; the arrays kept for the plots on the rows of test_d
            r.y_test, r.pred_before, r.pred_after = r.y_test[idx_te], r.pred_before[idx_te], r.pred_after[idx_te]
            targets[t] = r
            continue
        if t == Target.TAU_OUT:
            y, yt = train_d.tau_out_Nm, test_d.tau_out_Nm
            theta0 = baseline.theta.copy()
        else:
            assert train_d.q_in_rad is not None and test_d.q_in_rad is not None
            y, yt = train_d.tau_in_Nm + train_d.tau_out_Nm, test_d.tau_in_Nm + test_d.tau_out_Nm
            X0 = np.column_stack([train_d.q_in_rad, train_d.q_out_rad, np.ones(len(train_d))])
            X0t = np.column_stack([test_d.q_in_rad, test_d.q_out_rad, np.ones(len(test_d))])
        aug = Augmented(TargetData(t, kind, train, test, idx_tr, idx_te, y, yt, X0, X0t, v95), ctx,
                        baseline.alpha_s_rad, baseline.eta_s_rad_s, theta=theta0)
        targets[t], step = _close_target(aug, sp, labels, progress, step, total)
    trace = list(targets[Target.TAU_OUT].trace)
    for c in targets[Target.TAU_OUT].candidates if ds is None else []:
        if c.round == 1 and (c.effect.startswith("empirical:") or c.effect == "sensor_latency"):
            trace.append({"signal": c.depends_on[0], "explained": max(0.0, 1.0 - (1.0 - c.improvement) ** 2),
                          "improvement": c.improvement, "significant": c.significant})
    trace.sort(key=lambda d: -d["explained"])
    if progress:
        progress(total, total, "done")
    if ds is None:
        timings["candidates"] = time.perf_counter() - t1 - timings["baseline"]
    return ClosureResult(baseline, train_d, test_d, targets, trace, ds, timings)


def split_single(sig: Signals, train_fraction: float = 0.7) -> tuple[Signals, Signals]:
    """Split one run into a contiguous training head and a held-out tail (never random samples)."""
    n = len(sig)
    k = int(round(train_fraction * n))
    idx = np.arange(n)
    return sig.take(idx < k), sig.take(idx >= k)
