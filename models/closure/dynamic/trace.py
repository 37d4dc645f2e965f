"""The residual trace of the dynamic closure: which measured signal the dynamic baseline's
residual depends on (:func:`residual_trace`), the ranking that chooses the signals offered as
empirical in-model curves (:mod:`capstan.models.closure.dynamic.closure`).

It is additive and friction-like in the signal; an effect that acts through the simulation's
state is not additive in its own signal and can rank behind a proxy (measured on the
distributed model with a +6 % input load-cell gain: position, a proxy of the output torque in
a fixed environment, +54 % held-out, the load itself -23 %); the in-model candidates, not the
trace, name the mechanism.
"""

from __future__ import annotations

import math

import numpy as np

from capstan.models.closure.residual_trace import hat_weights, knots_for
from capstan.models.closure.scoring import _rmse
from capstan.models.closure.signals import Signals

#: knots of the trace's curves
TRACE_KNOTS = 12
#: rows per block of the trace's normal equations
TRACE_BLOCK_ROWS = 262_144


def _trace_rows(x: np.ndarray, s: np.ndarray, kn: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Column indices and values of the trace design's four non-zeros per row: the hat basis
    of ``x`` over ``kn`` (:func:`hat_weights`: two neighbouring knots), as is and times ``s``."""
    k = kn.shape[0]
    j, w = hat_weights(x, kn)
    return [j, j + 1, k + j, k + j + 1], [1.0 - w, w, s * (1.0 - w), s * w]


def _trace_normal_equations(x: np.ndarray, s: np.ndarray, r: np.ndarray, kn: np.ndarray,
                            G: np.ndarray, g: np.ndarray) -> None:
    """Add ``X^T X`` and ``X^T r`` of the trace design of these rows to ``G``, ``g`` (the design
    has four non-zeros per row: accumulated by index, no ``n x 2k`` matrix)."""
    k2 = G.shape[0]
    idx, val = _trace_rows(x, s, kn)
    acc = np.zeros((k2, k2))
    for a, (ia, va) in enumerate(zip(idx, val)):
        g += np.bincount(ia, va * r, minlength=k2)
        for ib, vb in list(zip(idx, val))[a:]:
            acc += np.bincount(ia * k2 + ib, va * vb, minlength=k2 * k2).reshape(k2, k2)
    G += acc + acc.T - np.diag(np.diag(acc))


def _trace_curve(x: np.ndarray, s: np.ndarray, kn: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """The trace design of these rows times ``coef``."""
    idx, val = _trace_rows(x, s, kn)
    return sum(v * coef[i] for i, v in zip(idx, val))


def residual_trace(r_tr: np.ndarray, r_te: np.ndarray, excluded: dict[str, str], train: Signals,
                   test: Signals) -> list[dict]:
    """How much of the dynamic residual (``r_tr`` on ``train``, ``r_te`` on ``test``, measured
    minus predicted [Nm]) each candidate signal explains: a piecewise-linear curve of the
    signal, additive and friction-like (times tanh(dq / 2 v_rest)), fitted on the training
    residual and scored on the held-out one. Sorted, best first; signals in ``excluded`` and
    the deflection (the elastic state the simulation carries) are not traced."""
    base = _rmse(r_te)
    s_tr = np.tanh(train.dq_out_rad_s / (2.0 * train.v_rest_rad_s))
    s_te = np.tanh(test.dq_out_rad_s / (2.0 * train.v_rest_rad_s))
    out = []
    for name in train.available():
        x, xt = train.signal(name), test.signal(name)
        if name in excluded or name == "deflection" or x is None or xt is None:
            continue
        kn = knots_for(x, TRACE_KNOTS)
        if kn is None:
            continue

        k2 = 2 * kn.size
        G = np.zeros((k2, k2))
        g = np.zeros(k2)
        for a in range(0, len(train), TRACE_BLOCK_ROWS):
            b = a + TRACE_BLOCK_ROWS
            _trace_normal_equations(x[a:b], s_tr[a:b], r_tr[a:b], kn, G, g)
        G[np.diag_indices_from(G)] += 1e-6 * max(float(np.trace(G)) / G.shape[0], 1e-12)
        coef = np.linalg.solve(G, g)
        sse = 0.0
        for a in range(0, len(test), TRACE_BLOCK_ROWS):
            b = a + TRACE_BLOCK_ROWS
            e = r_te[a:b] - _trace_curve(xt[a:b], s_te[a:b], kn, coef)
            sse += float(np.dot(e, e))
        imp = 1.0 - math.sqrt(sse / len(test)) / base if base > 0 else 0.0
        out.append({"signal": name, "explained": max(0.0, 1.0 - (1.0 - imp) ** 2), "improvement": float(imp),
                    "significant": False})
    out.sort(key=lambda d: -d["improvement"])
    return out
