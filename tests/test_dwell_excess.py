"""The breakaway excess of a learned dwell_stiction: ``amp_Nm`` scales the friction capacity,
its Stribeck peak included, in the closure's simulation and in the controller's feedforward
alike, so the excess at a motion onset is ``amp`` times the Stribeck factor at that speed.
Checked against the torsional unit's simulated breakaway peak (stick_slip) and the
feedforward's njit evaluation (effects_runtime)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capstan.models.closure.dynamic.candidates import dwell_breakaway_excess_Nm
from capstan.models.closure.effects_runtime import effect_loss_Nm, friction_shape
from capstan.models.transmission.stick_slip import simulate_unit

TAU_FC, ZETA_S, ETA_S = 1.0, 1.7, 2.0          # a wide Stribeck peak, as the link's refit finds it


def _breakaway_peak_Nm(cap_scale: float) -> float:
    """Peak friction of the unit (node pulled through a spring by a slow ramp, from rest) with
    its capacity scaled by ``cap_scale`` throughout [Nm]."""
    dt, n = 1e-3, 4000
    t = np.arange(n) * dt
    kx = 500.0
    a = kx * 0.002 * t                               # the spring's end moves at 2 mrad/s
    x, v, f = np.empty(n), np.empty(n), np.empty(n)
    done = simulate_unit(t, a, np.array([0, n]), np.zeros(1), np.zeros(1), np.full(1, kx), 1e5, TAU_FC, ZETA_S,
                         ETA_S, 0.0, x, v, f, np.full(n, cap_scale), 0.0, 1.0)
    assert done == n and np.max(v) > 1e-3            # it broke away
    return float(np.max(f))


def test_the_simulated_breakaway_rises_by_amp_times_the_stribeck_factor() -> None:
    coef, rest, tau_age = 0.8, 1.5, 1.0
    g = 1.0 - math.exp(-rest / tau_age)             # slide 0 at the onset
    excess = _breakaway_peak_Nm(1.0 + coef * g) - _breakaway_peak_Nm(1.0)
    amp_Nm = coef * TAU_FC                          # as the closure reports it (_named)
    # the onset here is slow (v << eta_s): the factor is zeta_s; amp alone is 1 / 1.7 of it
    expected = dwell_breakaway_excess_Nm(amp_Nm, tau_age, rest, ZETA_S, ETA_S, 0.0)
    assert excess == pytest.approx(expected, rel=0.01)
    assert excess == pytest.approx(amp_Nm * ZETA_S * g, rel=0.01)
    assert abs(excess - amp_Nm * g) > 0.5 * amp_Nm * g * (ZETA_S - 1.0)


@pytest.mark.parametrize("v", [0.05, 0.5, 3.0])
def test_the_feedforward_adds_the_same_excess_at_the_onset(v: float) -> None:
    amp, tau_age, s0, rest = 1.3, 0.7, 0.04, 2.0
    p = np.array([amp, tau_age, s0, 0, 0, 0, 0, 0], float)
    s = friction_shape(v, 1e4, ETA_S, ZETA_S)       # tanh(alpha v) = 1: the sign of the motion
    ff = effect_loss_Nm(1, p, np.zeros(2), np.zeros(2), np.zeros(2), s, v, 0.0, 0.0, rest, 0.0, 0.0, 0.0, 0.0)
    assert ff == pytest.approx(float(dwell_breakaway_excess_Nm(amp, tau_age, rest, ZETA_S, ETA_S, v)), rel=1e-12)
    # without a Stribeck peak the excess is amp (1 - exp(-rest / tau_age))
    assert dwell_breakaway_excess_Nm(amp, tau_age, rest, 1.0, ETA_S, v) == pytest.approx(
        amp * (1.0 - math.exp(-rest / tau_age)), rel=1e-12)


def test_the_excess_over_several_rests_is_one_per_rest() -> None:
    rests = np.array([0.3, 1.5, 0.7, 3.0])
    out = dwell_breakaway_excess_Nm(1.0, 1.0, rests, 1.0, 1.0, 0.0)
    assert out.shape == rests.shape and np.all(np.diff(out[np.argsort(rests)]) > 0.0)


def test_the_e2e_report_states_the_excess_at_an_onset() -> None:
    from capstan.tools.experiments.e2e_closure import _parameters

    s = {"injected": [{"effect": "dwell_stiction", "amp": 1.0, "tau_age_s": 1.0, "slide_rad": 0.05}],
         "learned": [{"effect": "dwell_stiction", "params": {"amp_Nm": 1.5, "tau_age_s": 1.0, "s0_rad": 0.04}}],
         "learned_shape": {"alpha_s_rad": 1.0, "eta_s_rad_s": 5.0, "zeta_s": 1.2, "v_rest_rad_s": 0.017},
         "runs": {"C": {"breakaway": {"median_sliding_Nm": 1.85}}}}
    onset = 1.5 * (1.0 + 0.2 * math.exp(-(0.05 / 5.0) ** 2))
    assert f"at an onset after a long rest {onset:.2f} Nm" in _parameters(s)[0]
