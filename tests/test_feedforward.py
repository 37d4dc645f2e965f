"""Friction feedforward (eqs 19, 21, 25) and gravity model inside the control step."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capstan.controller.law.config import ControllerConfig
from capstan.controller.law.core import Controller
from capstan.models.common.errors import ConfigError
from capstan.controller.law.feedforward import friction_curve_Nm, friction_torque_per_N
from capstan.models.common.errors import ConfigError
from capstan.models.transmission.pretension import Eq25Reading

MU = 0.052
R = 0.04


@pytest.mark.parametrize("theta", [0.3, 3.0, 6.0])
def test_friction_magnitude_uniform_routing_closed_form(theta):
    """Uniform routing, equal ends, tau_fc = mu theta T0_eq r_out with T0_eq per eq 25 reading:
    friction-preserving (default) 4 T0 (1 - exp(-mu theta/2)) / (mu theta); printed minimum
    2 T0 exp(-mu theta/2)."""
    routing = {"length_m": 1.379, "theta_rad": theta}
    cfg = ControllerConfig.from_mapping({"feedforward": {"routing": routing}})
    x = MU * theta
    assert cfg.feedforward.eq25_reading == Eq25Reading.FRICTION_PRESERVING
    assert friction_torque_per_N(cfg.feedforward, R) == pytest.approx(
        MU * theta * 4.0 * (1.0 - math.exp(-x / 2.0)) / x * R, rel=1e-9)
    cfg = ControllerConfig.from_mapping({"feedforward": {"routing": routing, "eq25_reading": "field_minimum"}})
    assert friction_torque_per_N(cfg.feedforward, R) == pytest.approx(MU * theta * 2.0 * math.exp(-x / 2.0) * R,
                                                                       rel=1e-9)
    # the choice round-trips through the logged config
    assert ControllerConfig.from_mapping(cfg.to_mapping()).feedforward.eq25_reading == Eq25Reading.FIELD_MINIMUM


def test_eq25_reading_rejects_unknown_value_naming_the_key():
    with pytest.raises(ConfigError, match=r"feedforward\.eq25_reading"):
        ControllerConfig.from_mapping({"feedforward": {"eq25_reading": "arc_length_mean"}})


def test_friction_magnitude_depends_on_total_bending_not_profile_shape():
    """With equal end pretensions the balanced point splits the bending in halves (eq 24)."""
    a = ControllerConfig.from_mapping({"feedforward": {"routing": {"length_m": 1.379, "theta_rad": 4.0}}})
    # same total bending 4 rad concentrated near the input: kappa 0 -> 16 -> 0 over 0.5 m (triangle, area 4)
    b = ControllerConfig.from_mapping({"feedforward": {"routing": {
        "curvature_profile": [[0.0, 0.0], [0.2, 16.0], [0.5, 0.0], [1.379, 0.0]]}}})
    assert b.feedforward.routing().theta_total_rad == pytest.approx(4.0, rel=1e-9)
    assert friction_torque_per_N(a.feedforward, R) == pytest.approx(friction_torque_per_N(b.feedforward, R), rel=1e-9)


def test_stribeck_shape_eq21():
    cfg = ControllerConfig.from_mapping({"feedforward": {"zeta_s": 1.5, "b_vis_Nms_rad": 0.1}}).feedforward
    tau_fc = 2.0
    v = np.array([-3.0, -0.5, 0.0, 0.5, 3.0])
    f = friction_curve_Nm(v, tau_fc, cfg)
    assert f[2] == 0.0
    assert np.allclose(f[::-1], -f)                       # odd
    # far above the Stribeck velocity: Coulomb level + viscous
    assert f[-1] == pytest.approx(tau_fc * 1.0 + 0.1 * 3.0, rel=1e-6)
    # near the Stribeck velocity the sticky factor raises it above Coulomb
    vs = cfg.eta_s_rad_s
    fs = friction_curve_Nm(np.array([vs]), tau_fc, cfg)[0]
    expected = math.tanh(cfg.alpha_s_rad * vs) * (1.0 + 0.5 * math.exp(-1.0)) * tau_fc + 0.1 * vs
    assert fs == pytest.approx(expected, rel=1e-12)


def _ctl(**ff):
    m = {"torque_loop": "ldo", "feedback": {"kp": 5.0, "kd_s": 0.05, "derivative_cutoff_hz": 40.0, "ki_1_s": 20.0,
                                                "deflection_damping_Nms_rad": 0.0, "rest_gate_cutoff_hz": 0.0, "band_gain": 0.0, "output_torque_gain": 0.0}, "gravity": {"enabled": True, "m_g_l_Nm": 3.78},
         "filters": {"q_out_blend_hz": 0.0},      # the raw angle: these cycles hold q with a rate
         # no slew limit: these tests check eq (21) cycle by cycle (the limit has its own test)
         "feedforward": dict({"enabled": True, "routing": {"length_m": 1.379, "theta_rad": 5.0},
                              "max_rate_Nm_s": 1e9}, **ff)}
    return Controller(ControllerConfig.from_mapping(m))


def _cycle(ctl, k, T0=150.0, q=0.4, dq=0.5, imu_new=1):
    rec = ctl.record[0]
    t = 1.0 + k * 1e-3
    rec["t_s"] = rec["lc_t_s"] = rec["imu_t_s"] = rec["motor_t_s"] = t
    rec["T_up_in_N"] = rec["T_up_out_N"] = rec["T_lo_out_N"] = rec["T_lo_in_N"] = T0
    rec["q_out_rad"], rec["dq_out_rad_s"], rec["imu_new"] = q, dq, imu_new
    ctl.step()
    return rec


def test_feedforward_reference_placement_and_scaling_with_measured_pretension():
    ctl = _ctl()
    rec = _cycle(ctl, 0, T0=150.0)
    tau_fc_150 = float(rec["tau_fc_Nm"])
    nominal = friction_torque_per_N(ctl.cfg.feedforward, R) * 150.0
    assert tau_fc_150 == pytest.approx(nominal, rel=1e-3)    # dq = 0.5 >> eta_s: Coulomb level
    assert rec["tau_g_Nm"] == pytest.approx(3.78 * math.sin(0.4))
    assert rec["tau_in_des_Nm"] == pytest.approx(rec["tau_g_Nm"] + tau_fc_150)
    rec = _cycle(ctl, 1, T0=300.0)
    assert float(rec["tau_fc_Nm"]) == pytest.approx(2.0 * tau_fc_150, rel=1e-9)


def test_feedforward_only_updates_on_new_imu_sample():
    ctl = _ctl()
    a = float(_cycle(ctl, 0, dq=0.5)["tau_fc_Nm"])
    b = float(_cycle(ctl, 1, dq=-0.5, imu_new=0)["tau_fc_Nm"])      # held
    c = float(_cycle(ctl, 2, dq=-0.5, imu_new=1)["tau_fc_Nm"])      # updated
    assert b == a and c == pytest.approx(-a)


def test_fixed_pretension_ignores_load_cells():
    ctl = _ctl(pretension="fixed", T0_fixed_N=100.0)
    rec = _cycle(ctl, 0, T0=250.0)
    assert float(rec["tau_fc_Nm"]) == pytest.approx(friction_torque_per_N(ctl.cfg.feedforward, R) * 100.0, rel=1e-3)


def test_motor_placement_keeps_feedforward_out_of_the_torque_reference():
    ref = _ctl(placement="reference")
    mot = _ctl(placement="motor")
    r1 = _cycle(ref, 0)
    r2 = _cycle(mot, 0)
    assert r2["tau_in_des_Nm"] == pytest.approx(r2["tau_g_Nm"])
    assert r1["tau_in_des_Nm"] == pytest.approx(r1["tau_g_Nm"] + r1["tau_fc_Nm"])
    # at the first cycle (tau_in = 0, d_hat from the initial tau_in = 0): raw = (1 + kp) tau_des [+ tau_fc]
    kp = ref.cfg.feedback.kp
    assert r1["tau_m_raw_Nm"] == pytest.approx((1 + kp) * r1["tau_in_des_Nm"])
    assert r2["tau_m_raw_Nm"] == pytest.approx((1 + kp) * r2["tau_in_des_Nm"] + r2["tau_fc_Nm"])


def test_gain_and_disable():
    half = _cycle(_ctl(gain=0.5), 0)
    full = _cycle(_ctl(), 0)
    off = _cycle(_ctl(enabled=False), 0)
    assert half["tau_fc_Nm"] == pytest.approx(0.5 * full["tau_fc_Nm"])
    assert off["tau_fc_Nm"] == 0.0


def test_step_uses_the_reduced_model_friction_law():
    """The step's feedforward equals models.reduced's eq (21) evaluated in plain Python
    (also guards against a stale Numba cache after models/transmission/reduced.py changes)."""
    from capstan.models.transmission.reduced import stribeck_friction_Nm

    ctl = _ctl()
    ff = ctl.cfg.feedforward
    for k, dq in enumerate((0.003, 0.04, -0.2, 1.5)):
        _cycle(ctl, 2 * k, T0=170.0, dq=dq)         # the gate opens on the 2nd sample in a row outside
        rec = _cycle(ctl, 2 * k + 1, T0=170.0, dq=dq)
        band = ff.dead_band_rad_s                                          # the rest gate
        gate = min(max((abs(dq) - 0.8 * band) / (0.2 * band), 0.0), 1.0)
        expected = gate * stribeck_friction_Nm.py_func(dq, ctl.friction_torque_per_N * 170.0, ff.zeta_s, ff.zeta_c,
                                                       ff.eta_s_rad_s, ff.alpha_s_rad, ff.b_vis_Nms_rad)
        assert float(rec["tau_fc_Nm"]) == pytest.approx(expected, rel=1e-12, abs=1e-15)


def test_direction_does_not_follow_gyro_noise_at_rest():
    """At rest, 2 mrad/s gyro noise (the HIL plant's and the Xsens' figure) must not flip
    the friction torque: the gate opens at 4 sigma (once in ~16000 samples), so the
    feedforward's std at rest is below 1 % of the friction torque; with the gate off (the
    old tanh(alpha dq)) the direction follows the noise (about half the samples flip)."""
    rng = np.random.default_rng(3)
    noise = rng.normal(0.0, 0.002, 4000)
    quiet = _ctl()
    m = {"feedforward": {"routing": {"length_m": 1.379, "theta_rad": 5.0}, "dead_band_rad_s": 0.0},
         "stability": {"gyro_noise_rad_s": 0.0}}    # the old feedforward: only allowed on noise-free rates
    buzzing = Controller(ControllerConfig.from_mapping(m))
    tq = np.array([float(_cycle(quiet, k, T0=150.0, dq=v)["tau_fc_Nm"]) for k, v in enumerate(noise)])
    tb = np.array([float(_cycle(buzzing, k, T0=150.0, dq=v)["tau_fc_Nm"]) for k, v in enumerate(noise)])
    tau_fc = quiet.friction_torque_per_N * 150.0
    flips = lambda t: int(np.sum(np.sign(t[1:]) * np.sign(t[:-1]) < 0))
    assert flips(tb) > 1000
    assert flips(tq) <= 8
    assert np.std(tq) < 0.01 * tau_fc < np.std(tb)


def test_rest_gate_is_continuous_and_leaves_moving_friction_unchanged():
    """The gate rises continuously from 0 at 0.8 x band to 1 at the band; from there on the
    feedforward is eq (21) itself (motion onset is not delayed), e.g. at 0.1 rad/s."""
    gated = _ctl()
    plain_cfg = {"feedforward": {"routing": {"length_m": 1.379, "theta_rad": 5.0}, "dead_band_rad_s": 0.0,
                                 "max_rate_Nm_s": 1e9},
                 "stability": {"gyro_noise_rad_s": 0.0}}
    plain = Controller(ControllerConfig.from_mapping(plain_cfg))
    band = gated.cfg.feedforward.dead_band_rad_s
    vals = []
    for k, v in enumerate((0.8 * band, 0.9 * band, band, 0.1)):
        _cycle(gated, 2 * k, T0=150.0, dq=v)
        g = float(_cycle(gated, 2 * k + 1, T0=150.0, dq=v)["tau_fc_Nm"])
        p = float(_cycle(plain, k, T0=150.0, dq=v)["tau_fc_Nm"])
        vals.append((g, p))
    assert vals[0][0] == 0.0
    assert vals[1][0] == pytest.approx(0.5 * vals[1][1], rel=1e-9)
    assert vals[2][0] == pytest.approx(vals[2][1], rel=1e-12) and vals[3][0] == pytest.approx(vals[3][1], rel=1e-12)


def test_rest_band_below_the_gyro_noise_is_refused():
    with pytest.raises(ConfigError, match="dead_band_rad_s"):
        ControllerConfig.from_mapping({"feedforward": {"dead_band_rad_s": 0.001},
                                       "stability": {"gyro_noise_rad_s": 0.002}})


def test_one_noise_sample_outside_the_gate_does_not_kick_the_command():
    """A single IMU sample beyond the gate's edge (a 4-sigma noise sample) gives no
    feedforward; two in a row (motion) do."""
    ctl = _ctl()
    band = ctl.cfg.feedforward.dead_band_rad_s
    seq = [0.0, 0.0, 1.5 * band, 0.0, 0.0, 1.5 * band, 1.5 * band]
    fc = [float(_cycle(ctl, k, T0=150.0, dq=v)["tau_fc_Nm"]) for k, v in enumerate(seq)]
    assert fc[:6] == [0.0] * 6 and fc[6] > 0.0


def test_feedforward_flip_at_a_fast_reversal_is_slew_limited():
    """At a fast reversal eq (21) flips sign within one IMU sample (2 x 2.4 Nm here); the step
    spreads it at feedforward.max_rate_Nm_s (200 Nm/s: 0.2 Nm per cycle), so the command never
    meets its 2 Nm/cycle rate clamp, and arrives at the flipped value after |flip| / 0.2 cycles."""
    free = _ctl(max_rate_Nm_s=1e9)
    lim = _ctl(max_rate_Nm_s=200.0)
    for ctl in (free, lim):
        for k in range(40):
            _cycle(ctl, k, dq=0.5)
    a = float(free.record[0]["tau_fc_Nm"])
    assert float(lim.record[0]["tau_fc_Nm"]) == pytest.approx(a)      # settled before the reversal
    fc = [float(_cycle(lim, 40 + k, dq=-0.5)["tau_fc_Nm"]) for k in range(60)]
    steps = np.abs(np.diff([a] + fc))
    assert np.max(steps) <= 0.2 + 1e-12
    n = int(math.ceil(2.0 * a / 0.2))
    assert fc[n - 2] > -a and fc[n] == pytest.approx(-a)
    assert float(_cycle(free, 40, dq=-0.5)["tau_fc_Nm"]) == pytest.approx(-a)   # eq (21) itself flips at once
    with pytest.raises(ConfigError, match="max_rate_Nm_s"):
        _ctl(max_rate_Nm_s=0.0)
