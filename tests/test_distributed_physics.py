"""Physics of the distributed tendon-sheath model, checked against closed forms:
capstan ratio, static stiffness, eq (19), slack range, hysteresis trends, boundary modes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capstan.models.distributed.model import (BoundaryParams, DistributedModel, InputMode, OutputMode,
                                TransmissionParams)
from capstan.models.common.errors import ConfigError, OperatingRangeError
from capstan.models.transmission.link import LinkParams

MU = 0.052
R = 0.04


def _run(model: DistributedModel, t_end_s: float, u_fn, adaptive: bool = False, dt_s: float = 1e-3):
    t = np.arange(0.0, t_end_s + 0.5 * dt_s, dt_s)
    return model.simulate(t, u_fn(t), adaptive=adaptive)


def _ramp_hold(level_Nm: float, t_ramp_s: float = 0.2):
    return lambda t: np.minimum(t / t_ramp_s, 1.0) * level_Nm


@pytest.mark.parametrize("n_nodes", [1, 10, 50])
def test_steady_sliding_reproduces_capstan_ratio(n_nodes: int) -> None:
    theta = 3.0
    # output is a pure damper: constant sliding speed ~0.2 rad/s, all nodes slide
    bnd = BoundaryParams(k_out_Nm_rad=0.0, b_out_Nms_rad=10.0)
    for sign in (1.0, -1.0):
        model = DistributedModel(TransmissionParams.uniform(n_nodes, theta, 150.0), bnd)
        res = _run(model, 2.5, _ramp_hold(4.0 * sign))
        assert abs(res.dq_out_rad_s[-1]) > 0.15
        f_u_in, f_u_out, f_l_out, f_l_in = res.fixture_tensions_N[-1]
        expected = math.exp(-sign * MU * theta)       # pull: tension decays towards output
        assert f_u_out / f_u_in == pytest.approx(expected, rel=0.01)
        assert f_l_in / f_l_out == pytest.approx(expected, rel=0.01)
        # the discrete model's exact sliding ratio converges to exp(-mu theta) as N grows
        c = MU * theta / (2 * n_nodes)
        discrete = ((1 - c) / (1 + c)) ** (n_nodes * sign)
        assert abs(discrete - expected) / expected < 0.1 * (MU * theta) ** 3 / n_nodes ** 2


@pytest.mark.parametrize("r_in, r_out", [(0.04, 0.04), (0.05, 0.03)])
def test_static_stiffness_without_friction_equals_Kc(r_in: float, r_out: float) -> None:
    trans = TransmissionParams.uniform(10, 3.0, 150.0, mu=0.0, r_in_m=r_in, r_out_m=r_out)
    model = DistributedModel(trans, BoundaryParams())
    res = _run(model, 3.0, _ramp_hold(5.0))
    deflection = res.q_in_rad[-1] - (r_out / r_in) * res.q_out_rad[-1]
    assert res.tau_out_Nm[-1] / deflection == pytest.approx(240.0, rel=0.005)
    assert res.tau_in_Nm[-1] / res.tau_out_Nm[-1] == pytest.approx(r_in / r_out, rel=0.005)
    # static output equilibrium of the testbed: tau_out = k_out q_out
    assert res.tau_out_Nm[-1] == pytest.approx(20.0 * res.q_out_rad[-1], rel=0.005)


def test_single_node_friction_torque_matches_eq19() -> None:
    theta, t0 = 3.0, 150.0
    model = DistributedModel(TransmissionParams.uniform(1, theta, t0),
                             BoundaryParams(k_out_Nm_rad=0.0, b_out_Nms_rad=0.5))
    res = _run(model, 1.5, _ramp_hold(6.0, 0.1))
    tens = res.fixture_tensions_N[-1]          # f01, f12, f34, f45 for N = 1
    eq19_model = MU * theta / 2 * tens.sum() * R
    eq19_closed = MU * theta * (2 * t0) * R     # (mu theta / 2)(sum of initial tensions) r
    # the tension sums (17)+(18) are invariant for linear springs
    assert eq19_model == pytest.approx(eq19_closed, rel=1e-6)
    dq = res.dq_out_rad_s[-1]
    assert dq > 4.0                                  # fast sliding: |eps| > 1 at the node
    tau_fc = res.tau_in_Nm[-1] - res.tau_out_Nm[-1] - 2 * 1.0 * R * R * dq   # minus r f_b (16)
    assert tau_fc == pytest.approx(eq19_closed, rel=0.01)


@pytest.mark.parametrize("pretension, theta, peak", [(150.0, 6.0, 10.0), (220.0, 0.3, 10.0),
                                                     (80.0, 6.0, 5.0)])
def test_tensions_stay_positive_in_operating_range(pretension: float, theta: float, peak: float) -> None:
    model = DistributedModel(TransmissionParams.uniform(10, theta, pretension), BoundaryParams())
    res = _run(model, 4.0, lambda t: peak * np.sin(2 * np.pi * 0.5 * t))
    assert res.tensions_upper_N.min() > 0.0 and res.tensions_lower_N.min() > 0.0
    assert np.all(np.isfinite(res.tau_out_Nm))


def test_slack_raises_operating_range_error() -> None:
    model = DistributedModel(TransmissionParams.uniform(10, 3.0, 30.0), BoundaryParams())
    with pytest.raises(OperatingRangeError, match="slack.*lower cable segment"):
        _run(model, 1.0, _ramp_hold(10.0, 0.5))
    model.reset()
    with pytest.raises(OperatingRangeError, match="slack"):
        for _ in range(1000):
            model.step(1e-3, -10.0)


def _hysteresis(pretension: float, theta: float) -> tuple[float, float]:
    """Backlash height (tau_in - tau_out at tau_in zero crossings) and loop slope."""
    model = DistributedModel(TransmissionParams.uniform(10, theta, pretension), BoundaryParams())
    res = _run(model, 6.0, lambda t: 10.0 * np.sin(2 * np.pi * 0.5 * t))
    last = res.t_s > 2.0
    tin, tout = res.tau_in_Nm[last], res.tau_out_Nm[last]
    cross = np.where(np.diff(np.sign(tin)) != 0)[0]
    height = float(np.mean(np.abs(tout[cross])))
    # slope of tau_in vs deflection where tau_in rises through [2, 8] Nm
    defl = (res.q_in_rad - res.q_out_rad)[last]
    rising = (np.gradient(tin) > 0) & (tin > 2.0) & (tin < 8.0)
    slope = float(np.polyfit(defl[rising], tin[rising], 1)[0])
    return height, slope


def test_hysteresis_grows_with_pretension_and_bending_and_slope_is_Kc() -> None:
    h80, s80 = _hysteresis(130.0, 3.0)   # 80 N would go slack at 10 Nm (r = 40 mm)
    h220, s220 = _hysteresis(220.0, 3.0)
    h_flat, _ = _hysteresis(150.0, 1.0)
    h_bent, s_bent = _hysteresis(150.0, 6.0)
    assert h220 > 1.3 * h80
    assert h_bent > 2.0 * h_flat
    # sliding slope: K_c (mu theta / 2) coth(mu theta / 2), i.e. K_c within 1 %
    for s, th in ((s80, 3.0), (s220, 3.0), (s_bent, 6.0)):
        a = MU * th / 2
        assert s == pytest.approx(240.0 * a / math.tanh(a), rel=0.02)


def test_motor_mode_oscillates_at_cable_natural_frequency() -> None:
    trans = TransmissionParams.uniform(5, 3.0, 150.0, mu=0.0)
    bnd = BoundaryParams(input_mode=InputMode.MOTOR, motor_damping_Nms_rad=0.0,
                         k_out_Nm_rad=1e7, b_out_Nms_rad=1e3)
    model = DistributedModel(trans, bnd)
    res = model.simulate(np.arange(0.0, 2.0, 1e-4), np.ones(20000), adaptive=True)
    k_eff = 1.0 / (1.0 / 240.0 + 1.0 / 1e7)
    x = res.q_in_rad - 1.0 / k_eff
    up = np.where((x[:-1] < 0) & (x[1:] >= 0))[0]
    period = np.mean(np.diff(res.t_s[up]))
    assert period == pytest.approx(2 * math.pi * math.sqrt(0.73 / k_eff), rel=0.005)
    assert np.max(res.q_in_rad) == pytest.approx(2.0 / k_eff, rel=0.01)


def test_link_mode_settles_at_gravity_equilibrium_with_external_torque() -> None:
    link = LinkParams(inertia_kg_m2=0.17, m_g_l_Nm=3.78, damping_Nms_rad=2.0)
    trans = TransmissionParams.uniform(5, 3.0, 150.0, mu=0.0)
    model = DistributedModel(trans, BoundaryParams(output_mode=OutputMode.LINK, link=link))
    t = np.arange(0.0, 6.0, 1e-3)
    res = model.simulate(t, np.full_like(t, 1.0), tau_ext_Nm=np.full_like(t, 0.5))
    assert 3.78 * math.sin(res.q_out_rad[-1]) == pytest.approx(1.5, rel=0.005)
    assert abs(res.dq_out_rad_s[-1]) < 1e-3


def test_effect_injection_between_steps() -> None:
    trans = TransmissionParams.uniform(10, 3.0, 150.0)
    model = DistributedModel(trans, BoundaryParams())
    model.shift_pretension(20.0)
    assert np.allclose(model.tensions_upper_N, trans.tension_upper_N + 20.0)
    model.reset()
    assert np.allclose(model.tensions_upper_N, trans.tension_upper_N)
    # mu_scale = 0 removes friction: static stiffness back to K_c
    model.mu_scale[:] = 0.0
    for _ in range(3000):
        model.step(1e-3, 5.0)
    assert model.tau_in_Nm / (model.q_in_rad - model.q_out_rad) == pytest.approx(240.0, rel=0.005)
    # cubic hardening makes the cable stiffer at the same torque
    model.reset()
    model.stiffness_cubic_1_m2 = 1e5
    model.reset()
    assert np.allclose(model.tensions_upper_N, trans.tension_upper_N)
    for _ in range(3000):
        model.step(1e-3, 5.0)
    assert model.tau_in_Nm / (model.q_in_rad - model.q_out_rad) > 1.1 * 240.0


def test_bad_parameters_name_the_key() -> None:
    with pytest.raises(ConfigError, match="tension_upper_N"):
        TransmissionParams(np.ones(3), np.ones(3), np.ones(3), np.ones(4))
    with pytest.raises(ConfigError, match="tension_lower_N"):
        TransmissionParams(np.ones(3), np.ones(3), np.ones(4), -np.ones(4))
    with pytest.raises(ConfigError, match="b_out_Nms_rad"):
        BoundaryParams(b_out_Nms_rad=0.0)
    with pytest.raises(ConfigError, match="u_Nm"):
        DistributedModel(TransmissionParams.uniform(2, 1.0, 100.0), BoundaryParams()).simulate(
            np.arange(3.0), np.zeros(2))
