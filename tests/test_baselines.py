"""Baselines of Fig. 11: Wu-type gated mapping, single-sided pretension, common predictor interface."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from capstan.models.transmission.baselines import (
    BaselineKind,
    GatedTransmission,
    PretensionAverage,
    fit_parameters,
    predict_tau_out,
    rmse_Nm,
    single_sided_model,
    single_sided_pretension_N,
    wu_model,
)
from capstan.models.common.errors import ModelError
from capstan.models.transmission.pretension import pretension_field
from capstan.models.transmission.reduced import ReducedModel, StribeckParams
from capstan.models.transmission.routing import Routing

MU, L, R = 0.052, 1.379, 0.04


def _sine(amp_Nm: float = 10.0, f_hz: float = 0.1, cycles: float = 2.0, dt_s: float = 1e-3):
    t = np.arange(0.0, cycles / f_hz + dt_s / 2, dt_s)
    return t, amp_Nm * np.sin(2 * np.pi * f_hz * t)


def _multisine(dt_s: float = 1e-3, duration_s: float = 20.0):
    t = np.arange(0.0, duration_s, dt_s)
    return t, 6.0 * np.sin(2 * np.pi * 0.1 * t) + 3.0 * np.sin(2 * np.pi * 0.27 * t + 1.0) \
        + 1.0 * np.sin(2 * np.pi * 0.61 * t + 0.3)


@pytest.mark.parametrize("theta_rad", [0.5, 3.0, 6.0])
@pytest.mark.parametrize("tau_in_Nm", [-8.0, 2.0, 9.0])
def test_wu_sliding_branch_follows_from_capstan_law_and_length_compatibility(theta_rad: float,
                                                                             tau_in_Nm: float) -> None:
    # independent statics: forward sliding on a constant-curvature sheath, pulled cable decays,
    # released cable grows; r (T1p - T2p) = tau_in; total elongation conserved int T1 + int T2 = 2 T0 L
    T0, kappa = 150.0, theta_rad / L
    i1, _ = quad(lambda s: math.exp(-MU * kappa * s), 0.0, L)
    i2, _ = quad(lambda s: math.exp(MU * kappa * s), 0.0, L)
    T1p, T2p = np.linalg.solve([[R, -R], [i1, i2]], [tau_in_Nm, 2 * T0 * L])
    tau_out = R * (T1p * math.exp(-MU * theta_rad) - T2p * math.exp(MU * theta_rad))
    wu = wu_model(MU * theta_rad, T0, R)
    assert wu.gain == 1.0
    assert tau_in_Nm - tau_out == pytest.approx(wu.threshold_Nm, rel=1e-9)


def test_wu_uniform_pretension_equals_eq19_with_undecayed_T0_eq() -> None:
    # the paper's claim: the Wu-type law is eq 19 with the uniform (undecayed) T0_eq = 2 T0
    wu = wu_model(MU * 3.0, 150.0, R)
    assert wu.threshold_Nm == pytest.approx(MU * 3.0 * (2 * 150.0) * R, rel=1e-14)


def test_wu_predictor_slides_at_threshold_and_sticks_between() -> None:
    wu = wu_model(MU * 3.0, 150.0, R, k_out_Nm_rad=20.0, b_out_Nms_rad=2.0)
    t, u = _sine()
    q, dq, out = wu.simulate(t, u)
    moving = dq != 0.0
    assert 0.2 < moving.mean() < 0.95
    assert np.allclose(np.abs(u - out)[moving], wu.threshold_Nm, rtol=1e-9)
    assert np.all(np.abs(u - out)[~moving] <= wu.threshold_Nm * (1 + 1e-9))
    # sticking output: q frozen, tau_out = k_out q (the damper torque vanishes abruptly)
    stuck = np.where(~moving[1:] & ~moving[:-1])[0] + 1
    assert np.all(q[stuck] == q[stuck - 1])


@pytest.mark.parametrize("tau_w_Nm", [0.5, 2.0, 4.0])
def test_wu_with_spring_output_is_a_play_operator(tau_w_Nm: float) -> None:
    A = 10.0
    g = GatedTransmission(1.0, tau_w_Nm, k_out_Nm_rad=20.0, b_out_Nms_rad=0.0)
    t, u = _sine(A)
    out = g.predict_tau_out(t, u)
    m = t >= 10.0
    area = abs(np.sum(0.5 * (out[m][1:] + out[m][:-1]) * np.diff(u[m])))
    assert area == pytest.approx(4 * tau_w_Nm * (A - tau_w_Nm), rel=0.005)
    assert out.max() == pytest.approx(A - tau_w_Nm, rel=1e-6)


def test_single_sided_average_closed_forms() -> None:
    T_a = 150.0
    for theta in (0.3, 3.0, 6.0):
        x = MU * theta
        closed = T_a * (1 - math.exp(-x)) / x
        r = Routing.uniform(L, theta)
        assert single_sided_pretension_N(r, MU, T_a) == pytest.approx(closed, rel=1e-6)
        assert single_sided_pretension_N(r, MU, T_a, PretensionAverage.BENDING) == pytest.approx(closed, rel=1e-13)
    bend_in = Routing.from_curvature_samples([0.0, 0.3, 0.6, L], [8.0, 8.0, 0.0, 0.0])
    bend_out = Routing.from_curvature_samples([0.0, L - 0.6, L - 0.3, L], [0.0, 0.0, 8.0, 8.0])
    assert bend_in.theta_total_rad == pytest.approx(bend_out.theta_total_rad)
    # a bend near the input fixture attenuates the one-sided field over most of the length
    assert single_sided_pretension_N(bend_in, MU, T_a) < single_sided_pretension_N(bend_out, MU, T_a)


def test_single_sided_threshold_lies_between_double_sided_and_wu() -> None:
    T0, theta = 150.0, 3.0
    r = Routing.uniform(L, theta)
    ss = single_sided_model(r, MU, T0, R)
    wu = wu_model(MU * theta, T0, R)
    reduced = ReducedModel.from_pretension(pretension_field(r, MU, T0, T0).T0_eq_N, MU, theta, R)
    assert ss.kind == BaselineKind.SINGLE_SIDED and wu.kind == BaselineKind.WU
    # bending-weighted single-sided: tau_w = 2 r T_a (1 - exp(-mu theta)) exactly
    ssb = single_sided_model(r, MU, T0, R, average=PretensionAverage.BENDING)
    assert ssb.threshold_Nm == pytest.approx(2 * R * T0 * (1 - math.exp(-MU * theta)), rel=1e-12)
    # undecayed > one-sided average > double-sided minimum (2 T0 e^{-x/2} vs 2 T0 (1 - e^{-x})/x)
    assert reduced.tau_fc_Nm < ss.threshold_Nm < wu.threshold_Nm


def test_reduced_with_sharp_coulomb_law_approaches_the_gated_model() -> None:
    tau_w = 1.7
    gated = GatedTransmission(1.0, tau_w, k_out_Nm_rad=20.0, b_out_Nms_rad=2.0)
    sharp = ReducedModel(tau_w, StribeckParams(zeta_s=1.0, alpha_s_rad=1e5), gamma_Nms_rad=1e-6)
    t, u = _multisine()
    assert rmse_Nm(predict_tau_out(t, u, sharp), predict_tau_out(t, u, gated)) < 0.01


def test_gated_transitions_are_abrupt_reduced_transitions_smooth() -> None:
    # the gated law switches tau_out from stick (d tau_out/dt = 0) to the sliding branch
    # (d tau_out/dt = d tau_in/dt) in one sample: a kink; the reduced model's tanh law bends smoothly
    t, u = _sine()
    gated = GatedTransmission(1.0, 1.7, k_out_Nm_rad=5.0, b_out_Nms_rad=8.0)
    smooth = ReducedModel(1.7, StribeckParams(zeta_s=1.0, alpha_s_rad=20.0), gamma_Nms_rad=0.05,
                          k_out_Nm_rad=5.0, b_out_Nms_rad=8.0)
    kink_gated = np.max(np.abs(np.diff(gated.predict_tau_out(t, u), 2)))
    kink_smooth = np.max(np.abs(np.diff(smooth.predict_tau_out(t, u), 2)))
    du_max = np.max(np.abs(np.diff(u)))
    assert kink_gated > 0.5 * du_max
    assert kink_smooth < 0.05 * kink_gated


@pytest.mark.parametrize("start", [(0.8, 0.5), (1.2, 3.0)])
def test_least_squares_recovers_wu_parameters(start: tuple[float, float]) -> None:
    t, u = _multisine()
    truth = GatedTransmission(1.0, 1.9, k_out_Nm_rad=20.0, b_out_Nms_rad=2.0)
    y = truth.predict_tau_out(t, u) + np.random.default_rng(1).normal(0.0, 0.05, t.size)
    fitted, rmse = fit_parameters(GatedTransmission(*start), ["gain", "threshold_Nm"], t, u, y)
    assert fitted.gain == pytest.approx(1.0, abs=0.01)
    assert fitted.threshold_Nm == pytest.approx(1.9, abs=0.03)
    assert rmse == pytest.approx(0.05, rel=0.1)


def test_least_squares_fits_nested_reduced_parameters() -> None:
    t, u = _multisine(dt_s=2e-3)
    truth = ReducedModel(1.7, StribeckParams(zeta_s=1.0))
    y = truth.predict_tau_out(t, u)
    fitted, rmse = fit_parameters(ReducedModel(1.0, StribeckParams(zeta_s=1.0)), ["tau_fc_Nm"], t, u, y,
                                  lower=[0.0], upper=[10.0])
    assert fitted.tau_fc_Nm == pytest.approx(1.7, rel=1e-3)
    with pytest.raises(ModelError):
        fit_parameters(truth, ["stribeck.nope"], t, u, y)


def test_gated_model_rejects_bad_parameters() -> None:
    with pytest.raises(ModelError):
        GatedTransmission(1.0, -0.1)
    with pytest.raises(ModelError):
        GatedTransmission(1.0, 1.0, k_out_Nm_rad=0.0, b_out_Nms_rad=0.0)
    with pytest.raises(ModelError):
        wu_model(-0.1, 150.0, R)
