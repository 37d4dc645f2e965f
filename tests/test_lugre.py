"""LuGre friction: steady state on the Stribeck curve, pre-sliding stiffness, hysteresis in the unit."""

from __future__ import annotations

import numpy as np
import pytest

from capstan.models.common.errors import ModelError
from capstan.models.transmission.lugre import LuGreParams, lugre_force_series, simulate_lugre_unit

P = LuGreParams(sigma0_Nm_rad=500.0, sigma1_Nms_rad=5.0, sigma2_Nms_rad=0.3, F_c_Nm=1.5, F_s_Nm=2.0,
                v_s_rad_s=0.05)


@pytest.mark.parametrize("v_rad_s", [0.005, 0.02, 0.05, 0.3, -0.1, -2.0])
def test_steady_state_is_stribeck_curve_plus_viscous(v_rad_s: float) -> None:
    # bristle time constant g(v) / (sigma0 |v|) <= 0.8 s: 15 s is > 18 time constants
    t = np.linspace(0.0, 15.0, 15001)
    F, z = lugre_force_series(P, t, np.full(t.size, v_rad_s))
    g = 1.5 + 0.5 * np.exp(-(v_rad_s / 0.05) ** 2)
    assert F[-1] == pytest.approx(np.sign(v_rad_s) * g + 0.3 * v_rad_s, rel=1e-6)
    assert z[-1] == pytest.approx(np.sign(v_rad_s) * g / 500.0, rel=1e-6)
    assert P.steady_state_Nm(v_rad_s) == pytest.approx(F[-1], rel=1e-6)


def test_presliding_stiffness_is_sigma0() -> None:
    # creep by 0.1 mrad, far below the bristle range F_c / sigma0 = 3 mrad
    t = np.linspace(0.0, 1.0, 1001)
    v = np.full(t.size, 1e-4)
    F, _ = lugre_force_series(P, t, v)
    x = v * t
    slope = np.polyfit(x, F - 0.3 * v - 5.0 * v, 1)[0]
    assert slope == pytest.approx(500.0, rel=0.02)


def test_unit_shows_hysteresis_and_slides_at_coulomb_level() -> None:
    t = np.arange(0.0, 20.0, 1e-3)
    u = 10.0 * np.sin(2 * np.pi * 0.1 * t)
    q, dq, out, fr = simulate_lugre_unit(P, t, u, gamma_Nms_rad=0.01, k_out_Nm_rad=20.0, b_out_Nms_rad=0.0)
    assert np.all(np.isfinite(out))
    # steady sliding: |dq| > 0.2 rad/s for the last 0.2 s (> 10 bristle time constants g / (sigma0 |v|))
    fast = np.abs(dq) > 0.2
    window = 200
    run = np.convolve(fast.astype(float), np.ones(window), mode="full")[: t.size]
    sliding = run >= window
    assert sliding.sum() > 1000
    diff = (u - out)[sliding]
    expected = np.sign(dq[sliding]) * (1.5 + 0.3 * np.abs(dq[sliding]))
    assert np.max(np.abs(diff - expected - 0.01 * dq[sliding])) < 0.02
    m = t >= 10.0
    area = abs(np.sum(0.5 * (out[m][1:] + out[m][:-1]) * np.diff(u[m])))
    assert area > 0.5 * 4 * 1.5 * (10 - 1.5)


def test_invalid_parameters_raise() -> None:
    with pytest.raises(ModelError):
        LuGreParams(F_s_Nm=1.0, F_c_Nm=2.0)
    with pytest.raises(ModelError):
        LuGreParams(sigma0_Nm_rad=0.0)
