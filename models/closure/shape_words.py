"""Words for the shape of an effect over its signal, and its size over the data's support.

The description names the shape the data support -- a step is a step, an exponential
relaxation "relaxes with time constant ~tau", a line "rises about linearly" -- and every
magnitude is quoted over the *support* of the signal, its 5th to 95th percentile in the
training runs (:data:`SUPPORT_PERCENTILES`), never extrapolated beyond it.

A slow signal's curve (:data:`SLOW_SIGNALS`) is compared with three forms on a dense grid over
the support (:func:`slow_shape`): a line, a step at one instant (the best breakpoint), and a
saturating exponential ``a + b exp(-(x - x_lo) / tau)`` (the best ``tau`` on a log grid); the
form with the least squared error names the shape, a line unless another form leaves less
than ``PREFER_LINE`` of the line's squared error.
"""

from __future__ import annotations

import math

import numpy as np

#: the support of a signal: these percentiles of its training values
SUPPORT_PERCENTILES = (5.0, 95.0)
#: signals whose curves are compared with a step and an exponential beside the line
SLOW_SIGNALS = ("time",)
#: another form names the shape when it leaves less than this share of the line's squared error
PREFER_LINE = 0.5
#: points of the dense grid over the support
N_DENSE = 256


def support(x: np.ndarray) -> tuple[float, float]:
    """The 5th and 95th percentile of ``x`` (:data:`SUPPORT_PERCENTILES`)."""
    lo, hi = np.percentile(x, SUPPORT_PERCENTILES)
    return float(lo), float(hi)


def on_support(knots: np.ndarray, f: np.ndarray, sup: tuple[float, float] | None) -> tuple[np.ndarray, np.ndarray]:
    """(dense grid over ``sup`` (the knots' span if None), the piecewise-linear curve
    ``f`` at ``knots`` evaluated on it)."""
    lo, hi = sup if sup is not None else (float(knots[0]), float(knots[-1]))
    xs = np.linspace(lo, hi, N_DENSE)
    return xs, np.interp(xs, knots, f)


def slow_shape(xs: np.ndarray, y: np.ndarray, unit: str = "") -> tuple[str, str]:
    """(form, words) of the curve ``y(xs)`` (module docstring): form "linear", "step" or
    "exponential"; the words quote its change over ``xs``."""
    n = xs.size
    A = np.column_stack([np.ones(n), xs])
    lin, *_ = np.linalg.lstsq(A, y, rcond=None)
    sse_lin = float(np.sum((y - A @ lin) ** 2))
    u = unit or "unit"
    slope = float(lin[1])
    best = ("linear", sse_lin, f"{'rises' if slope > 0 else 'falls'} about linearly ({slope:.3g} Nm per {u}, "
                               f"{abs(slope) * float(xs[-1] - xs[0]):.3g} Nm over {xs[0]:.3g}-{xs[-1]:.3g} {u})")
    cs, cs2 = np.cumsum(y), np.cumsum(y * y)
    for i in range(n // 20, n - n // 20):
        left, right = cs[i - 1] / i, (cs[-1] - cs[i - 1]) / (n - i)
        sse = float(cs2[-1] - i * left ** 2 - (n - i) * right ** 2)
        if sse < best[1] and sse < PREFER_LINE * sse_lin:
            d = right - left
            best = ("step", sse, f"steps {'up' if d > 0 else 'down'} by {abs(d):.3g} Nm at {xs[i]:.3g} {unit}".rstrip())
    span = float(xs[-1] - xs[0])
    for tau in span * np.geomspace(0.02, 2.0, 40):
        B = np.column_stack([np.ones(n), np.exp(-(xs - xs[0]) / tau)])
        c, *_ = np.linalg.lstsq(B, y, rcond=None)
        sse = float(np.sum((y - B @ c) ** 2))
        if sse < best[1] and sse < PREFER_LINE * sse_lin:
            change = float(c[1]) * (math.exp(-span / tau) - 1.0)
            best = ("exponential", sse, f"{'rises' if change > 0 else 'falls'} and relaxes with time constant "
                                        f"~{tau:.3g} {u}: {abs(change):.3g} Nm over {xs[0]:.3g}-{xs[-1]:.3g} {u}")
    return best[0], best[2]


def relaxation_words(d_Nm: float, tau_r_s: float, sup_s: tuple[float, float]) -> str:
    """Words of ``pretension_relaxation`` (capacity + ``d (1 - exp(-t / tau_r))``), its change
    over the support ``sup_s`` of the run time."""
    t5, t95 = sup_s
    change = d_Nm * (math.exp(-t5 / tau_r_s) - math.exp(-t95 / tau_r_s))
    return (f"the friction {'rises' if d_Nm > 0 else 'falls'} and relaxes with time constant ~{tau_r_s:.3g} s in "
            f"each run: {abs(change):.3g} Nm over t = {t5:.3g}-{t95:.3g} s (5-95 % of the data)")

