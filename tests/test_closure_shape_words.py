"""The words of an effect's shape (models/closure/shape_words.py) and the empirical curve's
description over its support (models/closure/residual_trace.py ``describe_curve``): a step is
called a step, an exponential relaxation "relaxes with time constant ~tau", a line "about
linearly", and magnitudes are quoted over the 5-95 % support of the signal, not the extreme
knots. Curves written here in closed form (not the closure's own fits)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from capstan.models.closure.residual_trace import describe_curve
from capstan.models.closure.shape_words import relaxation_words, slow_shape, support

X = np.linspace(0.4, 7.6, 256)          # the 5-95 % support of an 8 s run


def _number(pattern: str, text: str) -> float:
    m = re.search(pattern, text)
    assert m, text
    return float(m.group(1))


def test_a_step_is_called_a_step_at_its_instant_with_its_height() -> None:
    form, words = slow_shape(X, np.where(X >= 4.0, -0.3, 0.0), "s")
    assert form == "step" and "steps down" in words
    assert _number(r"by ([\d.]+) Nm", words) == pytest.approx(0.3, rel=0.02)
    assert _number(r"at ([\d.]+) s", words) == pytest.approx(4.0, abs=0.05)


@pytest.mark.parametrize("tau_s", [1.0, 4.0])
def test_an_exponential_relaxation_is_named_with_its_time_constant(tau_s: float) -> None:
    y = -0.5 * (1.0 - np.exp(-X / tau_s))
    form, words = slow_shape(X, y + 0.002 * np.random.default_rng(1).standard_normal(X.size), "s")
    assert form == "exponential" and "relaxes with time constant" in words and "falls" in words
    assert _number(r"~([\d.]+) s", words) == pytest.approx(tau_s, rel=0.2)       # the 20 % bar
    # its size is the change over the support, not the asymptote
    assert _number(r": ([\d.]+) Nm", words) == pytest.approx(float(np.ptp(y)), rel=0.05)


def test_a_line_stays_a_line() -> None:
    form, words = slow_shape(X, 0.01 * X + 0.002 * np.random.default_rng(2).standard_normal(X.size), "s")
    assert form == "linear" and "rises about linearly" in words


def test_the_catalogued_forms_words_quote_the_support() -> None:
    w = relaxation_words(-0.7, 4.0, (0.4, 7.6))
    assert "relaxes with time constant ~4 s" in w and "falls" in w
    assert _number(r": ([\d.]+) Nm", w) == pytest.approx(0.7 * (np.exp(-0.1) - np.exp(-1.9)), rel=1e-3)


def test_an_empirical_curves_peak_to_peak_is_over_the_support_not_the_extreme_knots() -> None:
    # a velocity curve flat over the data but with a wild end knot (few samples out there)
    rng = np.random.default_rng(0)
    v = np.concatenate([rng.uniform(-1.0, 1.0, 10_000), [-6.0, 6.0]])
    knots = np.array([-6.0, -0.5, 0.0, 0.5, 6.0])
    odd = np.array([-3.0, -0.05, 0.0, 0.05, 3.0])
    d = describe_curve("velocity", knots, np.concatenate([np.zeros(5), odd]), "rad/s", sup=support(v))
    lo, hi = d["support"]
    assert lo == pytest.approx(-0.9, abs=0.03) and hi == pytest.approx(0.9, abs=0.03)
    # over +-0.9 rad/s the curve spans -0.05 - 0.4 * 2.95 / 5.5 ... +: about 0.53 Nm, not the knots' 6 Nm
    expect = 2.0 * (0.05 + (0.9 - 0.5) * (3.0 - 0.05) / 5.5)
    assert d["peak_to_peak_Nm"] == pytest.approx(expect, rel=0.05)
    assert f"peak-to-peak {d['peak_to_peak_Nm']:.3g} Nm over" in d["text"]
