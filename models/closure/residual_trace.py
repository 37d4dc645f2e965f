"""Signal attribution of a residual: how much of it each candidate signal explains.

For every candidate signal ``x`` (velocity, acceleration, position, dwell, time, load,
deflection, tension and each extra channel) the residual is regressed on a smooth
non-parametric function of ``x``: a piecewise-linear curve over ``N_KNOTS`` knots at
the training quantiles of ``x``, once as is (an additive term) and once multiplied by
the friction shape s(dq) (a friction-like term, odd in the motion direction). The
curve is fitted on the training data and scored on held-out data like a catalogue
effect, under the name ``empirical:<signal>``. Latency is traced by the catalogue's
time-shift candidate.

These empirical candidates serve two purposes: the attribution table (which signal
explains how much), and the honest fallback when no catalogued form fits: the report
then says which signal the residual depends on and how (:func:`describe_curve`),
instead of forcing an effect.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from capstan.models.closure.effects import EffectSpec, FeatureContext, Shape, Target
from capstan.models.closure.shape_words import SLOW_SIGNALS, on_support, slow_shape
from capstan.models.closure.signals import Signals

#: knots per empirical curve
N_KNOTS = 40


def hat_weights(x: np.ndarray, knots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(j, w)``: each value's left knot index and its weight on the right knot, so the
    piecewise-linear basis is ``1 - w`` at knot ``j`` and ``w`` at ``j + 1`` (constant beyond the ends)."""
    xc = np.clip(x, knots[0], knots[-1])
    j = np.clip(np.searchsorted(knots, xc, side="right") - 1, 0, knots.shape[0] - 2)
    return j, (xc - knots[j]) / np.maximum(knots[j + 1] - knots[j], 1e-300)


def hat_basis(x: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """Piecewise-linear interpolation basis (n x len(knots)); constant beyond the ends."""
    n, k = x.shape[0], knots.shape[0]
    j, w = hat_weights(x, knots)
    B = np.zeros((n, k))
    rows = np.arange(n)
    B[rows, j] = 1.0 - w
    B[rows, j + 1] += w
    return B


def knots_for(x: np.ndarray, n_knots: int = N_KNOTS) -> np.ndarray | None:
    """Knots at the quantiles of ``x`` (unique); None if ``x`` is (nearly) constant."""
    kn = np.unique(np.quantile(x, np.linspace(0.0, 1.0, n_knots)))
    span = float(np.ptp(x))
    if kn.size < 3 or span <= 0:
        return None
    keep = np.concatenate([[True], np.diff(kn) > 1e-9 * span])
    kn = kn[keep]
    return kn if kn.size >= 3 else None


def _f_empirical(sig: Signals, ctx: FeatureContext, sh: Shape, signal: str, knots: np.ndarray,
                 additive: bool = True) -> np.ndarray:
    x = sig.signal(signal)
    assert x is not None
    H = hat_basis(x, knots)
    s = ctx.baseline.friction_shape(sig.dq_out_rad_s)
    return np.hstack([H, s[:, None] * H]) if additive else np.hstack([0.0 * H, s[:, None] * H])


#: signals that must not enter the output-torque prediction additively: the output
#: torque is a function of them through the environment (tau_out = k_out q + b_out dq) or
#: the elastic path (tau_in + tau_out = 2 K_c defl), so an additive curve would rebuild
#: the measurement instead of finding a missing effect
NO_ADDITIVE = ("position", "deflection")


def empirical_candidates(train: Signals) -> list[EffectSpec]:
    """One ``empirical:<signal>`` candidate per candidate signal available in ``train``."""
    out = []
    for name in train.available():
        x = train.signal(name)
        if x is None or name == "deflection":
            continue
        kn = knots_for(x)
        if kn is None:
            continue
        coef = tuple(f"even_{i}" for i in range(kn.size)) + tuple(f"odd_{i}" for i in range(kn.size))
        out.append(EffectSpec(f"empirical:{name}", (name,), "not in the catalogue: a smooth function of "
                              f"{name}, additive and friction-like", f"f({name}) + s(dq) g({name})", coef,
                              ({"knots": ",".join(f"{k:.9g}" for k in kn)},),
                              partial(_f_empirical, signal=name, knots=kn, additive=name not in NO_ADDITIVE),
                              Target.TAU_OUT, (name,), loss_sign=1.0))
    if train.deflection_rad is not None:
        x = train.deflection_rad
        kn = knots_for(x)
        if kn is not None:
            coef = tuple(f"even_{i}" for i in range(kn.size)) + tuple(f"odd_{i}" for i in range(kn.size))
            out.append(EffectSpec("empirical:deflection", ("deflection",), "not in the catalogue: a smooth "
                                  "function of the deflection on the elastic path", "f(defl) + s(dq) g(defl)", coef,
                                  ({"knots": ",".join(f"{k:.9g}" for k in kn)},),
                                  partial(_f_empirical, signal="deflection", knots=kn), Target.ELASTIC,
                                  ("deflection",), loss_sign=1.0))
    return out


def is_empirical(spec: EffectSpec) -> bool:
    """True for the non-parametric fallback candidates."""
    return spec.name.startswith("empirical:")


def describe_curve(signal: str, knots: np.ndarray, coef: np.ndarray, unit: str = "",
                   sup: tuple[float, float] | None = None) -> dict:
    """Describe how the residual depends on ``signal`` from an empirical curve's coefficients.

    Returns ``{"signal", "part", "trend", "period", "peak_to_peak_Nm", "support", "text"}`` where
    ``part`` is "friction-like (odd in the motion direction)" or "additive". The peak-to-peak
    and the trend's magnitudes are over ``sup`` (the 5-95 % support of the signal's training
    values, :func:`capstan.models.closure.shape_words.support`; the knots' span if None); a slow
    signal's trend names a step or an exponential relaxation where the curve has that shape
    (:func:`capstan.models.closure.shape_words.slow_shape`).
    """
    k = knots.size
    even, odd = coef[:k], coef[k:2 * k]
    use_odd = float(np.std(odd)) > float(np.std(even))
    f = odd if use_odd else even
    part = "friction-like (changes sign with the motion direction)" if use_odd else "additive"
    slope = float(np.polyfit(knots, f, 1)[0]) if k >= 2 else 0.0
    detr = f - np.polyval(np.polyfit(knots, f, 1), knots)
    sign_changes = int(np.sum(np.diff(np.sign(detr[np.abs(detr) > 0.2 * np.max(np.abs(detr)) + 1e-15])) != 0))
    xs, fd = on_support(knots, f, sup)
    ptp = float(np.ptp(fd))
    lin_share = 1.0 - float(np.var(detr)) / max(float(np.var(f)), 1e-30)
    period = None
    if signal in SLOW_SIGNALS:
        trend = slow_shape(xs, fd, unit or "s")[1]
    elif sign_changes >= 4 and lin_share < 0.5:
        # dominant period from a dense resampling of the curve
        xs = np.linspace(knots[0], knots[-1], 512)
        ys = np.interp(xs, knots, detr)
        spec = np.abs(np.fft.rfft(ys - ys.mean()))
        j = int(np.argmax(spec[1:]) + 1)
        period = float((xs[-1] - xs[0]) / j * (512 / 511))
        trend = f"oscillates with a period of about {period:.3g} {unit}".strip()
    elif lin_share > 0.7:
        trend = f"{'rises' if slope > 0 else 'falls'} about linearly ({slope:.3g} Nm per {unit or 'unit'})"
    else:
        trend = f"varies non-monotonically ({sign_changes} turns)"
    text = (f"residual depends on {signal}: {part}, {trend}, peak-to-peak {ptp:.3g} Nm over "
            f"{xs[0]:.3g}-{xs[-1]:.3g} {unit}".rstrip() + "; no catalogued form explains it")
    return {"signal": signal, "part": part, "trend": trend, "period": period,
            "peak_to_peak_Nm": ptp, "support": [float(xs[0]), float(xs[-1])], "text": text}
