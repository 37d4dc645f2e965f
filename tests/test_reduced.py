"""Reduced model (eqs 19-21): nominal friction, Stribeck law, torsional-unit hysteresis."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

from capstan.models.common.errors import ConfigError, ModelError
from capstan.models.transmission.pretension import pretension_field, uniform_segment_tensions_N
from capstan.models.transmission.reduced import (
    ReducedModel,
    StribeckParams,
    eq19_friction_torque_Nm,
    nominal_friction_torque_Nm,
    stribeck_friction_Nm,
)
from capstan.models.transmission.routing import Routing

MU, L, R = 0.052, 1.379, 0.04
COULOMB = StribeckParams(zeta_s=1.0, zeta_c=1.0, eta_s_rad_s=0.05, alpha_s_rad=2000.0, b_vis_Nms_rad=0.0)


def _sine(amp_Nm: float = 10.0, f_hz: float = 0.1, cycles: float = 2.0, dt_s: float = 1e-3):
    t = np.arange(0.0, cycles / f_hz + dt_s / 2, dt_s)
    return t, amp_Nm * np.sin(2 * np.pi * f_hz * t)


def _last_cycle_area(t: np.ndarray, u: np.ndarray, y: np.ndarray, period_s: float) -> float:
    """|loop integral of tau_out d tau_in| over the last full period [Nm^2]."""
    m = t >= t[-1] - period_s
    return abs(float(np.sum(0.5 * (y[m][1:] + y[m][:-1]) * np.diff(u[m]))))


# ---------------------------------------------------------------- eq 19
@pytest.mark.parametrize("routing", [Routing.uniform(L, 3.0),
                                     Routing.from_curvature_samples([0, 0.3, 0.7, 1.0, L], [5, 0, 0, 8, 1])])
def test_nominal_friction_equals_eq19_from_n1_segment_tensions(routing: Routing) -> None:
    f = pretension_field(routing, MU, 160.0, 140.0)
    up = uniform_segment_tensions_N(f.T0_eq_N, 1)  # the two springs of one cable at rest
    lo = up.copy()
    eq19 = eq19_friction_torque_Nm(up[0], up[1], lo[0], lo[1], MU, routing.theta_total_rad, R)
    assert nominal_friction_torque_Nm(f.T0_eq_N, MU, routing.theta_total_rad, R) == pytest.approx(eq19, rel=1e-14)
    # with the torque (q_in - q_out) redistribution of eqs (17)/(18) the sum is unchanged
    d = 37.0
    assert eq19_friction_torque_Nm(up[0] + d / 2, up[1] + d / 2, lo[0] - d / 2, lo[1] - d / 2, MU,
                                   routing.theta_total_rad, R) == pytest.approx(eq19, rel=1e-14)


def test_nominal_friction_uniform_symmetric_closed_form() -> None:
    T0, theta = 150.0, 3.0
    T0_eq = pretension_field(Routing.uniform(L, theta), MU, T0, T0).T0_eq_N
    expected = 2 * MU * theta * T0 * math.exp(-MU * theta / 2) * R
    assert nominal_friction_torque_Nm(T0_eq, MU, theta, R) == pytest.approx(expected, rel=1e-13)


def test_distributed_n1_steady_sliding_friction_equals_eq19() -> None:
    dist = pytest.importorskip("capstan.models.distributed.model")
    routing = Routing.uniform(L, 3.0)
    f = pretension_field(routing, MU, 150.0, 150.0)
    tens = uniform_segment_tensions_N(f.T0_eq_N, 1)
    th = routing.segment_bending_rad(1)
    # p = 1000: the smooth Coulomb law (13) creeps below mu f_N by < 0.1 % at these speeds (p = 100: ~3 %)
    tp = dist.TransmissionParams(th, th.copy(), tens, tens.copy(), mu=MU, p=1000.0, r_in_m=R, r_out_m=R)
    model = dist.DistributedModel(tp, dist.BoundaryParams(k_out_Nm_rad=20.0, b_out_Nms_rad=2.0))
    t, u = _sine(cycles=1.0)
    res = model.simulate(t, u)
    sliding = np.abs(res.dq_out_rad_s) > 0.05
    assert sliding.sum() > 3000
    tau_f = np.abs(res.tau_in_Nm - res.tau_out_Nm)[sliding]
    expected = nominal_friction_torque_Nm(f.T0_eq_N, MU, 3.0, R)
    assert np.all(np.abs(tau_f - expected) < 0.01 * expected)


# ---------------------------------------------------------------- eq 21
def test_stribeck_limits() -> None:
    tau_fc, zs, zc, eta, alpha, bvis = 1.7, 1.4, 1.0, 0.05, 5000.0, 0.3
    assert stribeck_friction_Nm(0.0, tau_fc, zs, zc, eta, alpha, bvis) == 0.0
    for v in (2.0, -3.0, 20.0):
        expected = math.copysign(zc * tau_fc, v) + bvis * v
        assert stribeck_friction_Nm(v, tau_fc, zs, zc, eta, alpha, bvis) == pytest.approx(expected, rel=1e-12)
    v = np.linspace(1e-5, 0.02, 4000)
    vals = np.array([stribeck_friction_Nm(x, tau_fc, zs, zc, eta, alpha, 0.0) for x in v])
    assert vals.max() == pytest.approx(zs * tau_fc, rel=0.01)  # peak near small velocity: zeta_s tau_fc
    assert v[np.argmax(vals)] < 0.2 * eta
    assert stribeck_friction_Nm(-0.01, tau_fc, zs, zc, eta, alpha, bvis) == pytest.approx(
        -stribeck_friction_Nm(0.01, tau_fc, zs, zc, eta, alpha, bvis))


def test_stribeck_is_callable_from_a_jitted_step() -> None:
    @njit
    def feedforward(dq: float) -> float:
        return stribeck_friction_Nm(dq, 1.0, 1.2, 1.0, 0.05, 200.0, 0.1)

    assert feedforward(1.0) == pytest.approx(1.1, rel=1e-6)


def test_stribeck_params_from_mapping_names_bad_keys() -> None:
    p = StribeckParams.from_mapping({"zeta_s": 1.5, "eta_s_rad_s": 0.02}, "friction.stribeck")
    assert (p.zeta_s, p.zeta_c, p.eta_s_rad_s) == (1.5, 1.0, 0.02)
    with pytest.raises(ConfigError) as exc:
        StribeckParams.from_mapping({"zeta_s": 0.5}, "friction.stribeck")
    assert exc.value.key == "friction.stribeck.zeta_s"
    with pytest.raises(ConfigError) as exc:
        StribeckParams.from_mapping({"eta_s": 0.5}, "friction.stribeck")
    assert exc.value.key == "friction.stribeck.eta_s"
    with pytest.raises(ConfigError) as exc:
        ReducedModel.from_mapping({"gamma_Nms_rad": 0.01}, "reduced")
    assert exc.value.key == "reduced.tau_fc_Nm"


# ---------------------------------------------------------------- eq 20
def test_steady_sliding_difference_is_coulomb_friction() -> None:
    m = ReducedModel(tau_fc_Nm=1.7, stribeck=StribeckParams(zeta_s=1.3), gamma_Nms_rad=1e-3)
    t, u = _sine()
    q, dq, out = m.simulate(t, u)
    sliding = np.abs(dq) > 5 * m.stribeck.eta_s_rad_s
    assert sliding.sum() > 2000
    diff = (u - out)[sliding]
    # tau_in - tau_out = tau_hat(dq) + gamma dq -> sign(dq) zeta_c tau_fc (+ < 1e-3 Nm)
    assert np.all(np.abs(diff - np.sign(dq[sliding]) * 1.7) < 0.005 * 1.7 + 1e-3 * np.abs(dq[sliding]))


@pytest.mark.parametrize("tau_fc_Nm", [0.5, 1.7, 3.0])
def test_spring_output_loop_is_a_play_operator_of_half_width_tau_fc(tau_fc_Nm: float) -> None:
    # pure spring output + Coulomb-like friction: parallelogram loop, width 2 tau_fc,
    # height 2 (A - tau_fc) -> area 4 tau_fc (A - tau_fc); at tau_in = 0 tau_out = -/+ tau_fc
    A = 10.0
    m = ReducedModel(tau_fc_Nm, COULOMB, gamma_Nms_rad=1e-3, k_out_Nm_rad=20.0, b_out_Nms_rad=0.0)
    t, u = _sine(A)
    _, _, out = m.simulate(t, u)
    area = _last_cycle_area(t, u, out, 10.0)
    assert area == pytest.approx(4 * tau_fc_Nm * (A - tau_fc_Nm), rel=0.02)
    last = t >= 10.0
    up = np.where(last[1:] & (u[:-1] < 0) & (u[1:] >= 0))[0]
    down = np.where(last[1:] & (u[:-1] > 0) & (u[1:] <= 0))[0]
    assert out[up[0]] == pytest.approx(-tau_fc_Nm, rel=0.02)
    assert out[down[0]] == pytest.approx(tau_fc_Nm, rel=0.02)


def test_more_pretension_or_bending_widens_the_hysteresis() -> None:
    t, u = _sine()
    areas = {}
    for T0 in (80.0, 150.0, 220.0):
        for theta in (0.3, 3.0, 6.0):
            f = pretension_field(Routing.uniform(L, theta), MU, T0, T0)
            m = ReducedModel.from_pretension(f.T0_eq_N, MU, theta, R)
            areas[T0, theta] = _last_cycle_area(t, u, m.predict_tau_out(t, u), 10.0)
    for theta in (0.3, 3.0, 6.0):
        assert areas[80.0, theta] < areas[150.0, theta] < areas[220.0, theta]
    for T0 in (80.0, 150.0, 220.0):
        assert areas[T0, 0.3] < areas[T0, 3.0] < areas[T0, 6.0]


def test_implicit_step_is_stable_for_vanishing_gamma_and_coarse_steps() -> None:
    t_fine, u_fine = _sine(dt_s=1e-4)
    t_coarse, u_coarse = _sine(dt_s=2.5e-3)
    # monotone friction law (zeta_s = zeta_c), gamma = 0: the velocity is algebraic, the
    # backward-Euler solution converges smoothly as the step shrinks
    mono = ReducedModel(1.7, COULOMB, gamma_Nms_rad=0.0, k_out_Nm_rad=20.0, b_out_Nms_rad=0.5)
    diff = np.interp(t_coarse, t_fine, mono.predict_tau_out(t_fine, u_fine)) - mono.predict_tau_out(t_coarse, u_coarse)
    assert np.max(np.abs(diff)) < 0.01
    # Stribeck dip steeper than the output damping: breakaway is a velocity jump (stick-slip);
    # a coarse step only shifts the jump by < one step, so the error stays local
    strib = ReducedModel(1.7, StribeckParams(zeta_s=1.3), gamma_Nms_rad=0.0, k_out_Nm_rad=20.0, b_out_Nms_rad=0.5)
    out_coarse = strib.predict_tau_out(t_coarse, u_coarse)
    assert np.all(np.isfinite(out_coarse))
    diff = np.interp(t_coarse, t_fine, strib.predict_tau_out(t_fine, u_fine)) - out_coarse
    assert np.sqrt(np.mean(diff**2)) < 0.03
    assert np.mean(np.abs(diff) > 0.05) < 0.01
    # gamma -> 0 is a regular limit
    tiny = ReducedModel(1.7, StribeckParams(zeta_s=1.3), gamma_Nms_rad=1e-7, k_out_Nm_rad=20.0, b_out_Nms_rad=0.5)
    assert np.max(np.abs(tiny.predict_tau_out(t_coarse, u_coarse) - out_coarse)) < 1e-3


def test_given_output_mode_sticks_inside_and_slides_outside_the_friction_band() -> None:
    m = ReducedModel(1.7, COULOMB, gamma_Nms_rad=0.01)
    t = np.linspace(0.0, 1.0, 101)
    u = np.full(t.size, 5.0)
    _, dq_stick, _ = m.simulate(t, u, tau_out_Nm=u - 0.5 * 1.7)
    # creep on the tanh flank only: tau_fc tanh(alpha v) = tau_fc / 2 (gamma v ~ 3e-6 Nm negligible)
    assert np.allclose(dq_stick, math.atanh(0.5) / 2000.0, rtol=1e-3)
    _, dq_slide, out = m.simulate(t, u, tau_out_Nm=u - 1.7 - 0.2)
    # gamma v + tau_fc tanh(alpha v) = tau_fc + 0.2 -> v = 0.2 / gamma
    assert dq_slide[-1] == pytest.approx(0.2 / 0.01, rel=1e-6)
    assert np.allclose(out, u - 1.9, rtol=0, atol=1e-12)


def test_bad_series_raise_model_error() -> None:
    m = ReducedModel(1.0)
    with pytest.raises(ModelError):
        m.simulate([0.0, 0.1, 0.1], [0.0, 1.0, 2.0])
    with pytest.raises(ModelError):
        m.simulate([0.0, 0.1], [0.0])
    with pytest.raises(ModelError):
        ReducedModel(-1.0)
