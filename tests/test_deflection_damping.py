"""The deflection-rate damping (``controller.feedback.deflection_damping_Nms_rad``): the loop
model's filters against the compiled step, its effect on the stick modes against physics and
against a time-domain run of the step, and what it must not do (brake a steady motion, act at rest)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from capstan.controller.law.config import ControllerConfig
from capstan.controller.law.core import Controller
from capstan.controller.law.loop_model import (PlantPoint, closed_loop_poles, deflection_link_filter,
                                               deflection_reference_filter)
from test_torque_loop import OLD_LOOP, PREV_JC, _quiet, _run_step_physical

#: the strongest torque feedback inside the margins (shipped: kp 0.75, b 60, link 30 Hz with its lag
#: compensated), without the rest gate (the linear loop the analysis has)
SHIPPED_LINEAR = {"kp": 1.25, "deflection_damping_Nms_rad": 100.0, "deflection_link_cutoff_hz": 150.0,
                  "deflection_link_lag_compensation": False, "rest_gate_cutoff_hz": 0.0, "ki_1_s": 0.0, "output_torque_gain": 0.0,
                  "inertia_comp_kg_m2": 0.0}
SHEATH_STICK = PlantPoint(3300.0, 0.51, 0.5)        # the grid point that limits the phase margin


def _linear(fb: dict) -> ControllerConfig:
    m = _quiet({"feedback": fb})
    m["feedforward"]["dead_band_rad_s"] = 0.0       # rest gate open: the linear loop
    m["stability"] = {"gyro_noise_rad_s": 0.0}      # (allowed only for a noiseless gyro)
    return ControllerConfig.from_mapping(m)


def _pulse_run(cfg: ControllerConfig, field: str, x: np.ndarray) -> np.ndarray:
    """The step's command for the input ``field`` = x (all else constant, IMU every cycle)."""
    ctl = Controller(cfg)
    r = ctl.record[0]
    u = np.zeros(len(x))
    for k in range(len(x)):
        r["t_s"] = r["lc_t_s"] = r["imu_t_s"] = r["motor_t_s"] = k * cfg.dt_s
        r["T_up_in_N"] = r["T_lo_in_N"] = r["T_up_out_N"] = r["T_lo_out_N"] = 150.0
        r["imu_new"] = 1
        r["dq_m_rad_s"] = r["dq_out_rad_s"] = r["tau_out_ref_Nm"] = 0.0
        r[field] = x[k]
        u[k] = ctl.step()
    return u


@pytest.mark.slow
def test_the_analysis_filters_are_the_steps():
    """The loop model's paths reproduce the compiled step to rounding: the motor velocity
    enters as -b dq_m; the link's as b H_l (with the IMU running every cycle here, H_l without the
    one cycle that stands for the 400 Hz hold); the reference as b H_r on top of the reference."""
    cfg = _linear({**SHIPPED_LINEAR, "kp": 0.0, "deflection_link_cutoff_hz": 40.0, "deflection_reference_cutoff_hz": 3.0,
                   "motor_velocity": "drive"})     # the drive's velocity in: the observer's paths are test_motor_velocity's
    b = 100.0
    x = np.zeros(300)
    x[5] = 1e-2
    assert np.max(np.abs(_pulse_run(cfg, "dq_m_rad_s", x) + b * x)) < 1e-12
    hl = deflection_link_filter(cfg)
    u = _pulse_run(cfg, "dq_out_rad_s", x)
    assert hl[0][0] == 0.0
    assert np.max(np.abs(u - b * signal.lfilter(hl[0][1:], hl[1], x))) < 1e-9 * np.max(np.abs(u))
    ref = np.concatenate((np.zeros(5), np.full(295, 0.5)))      # a step of the torque reference
    hr = deflection_reference_filter(cfg)
    u = _pulse_run(cfg, "tau_out_ref_Nm", ref)
    assert np.max(np.abs(u - ref - b * signal.lfilter(hr[0], hr[1], ref))) < 1e-9 * np.max(np.abs(u))


def _mode(poles: np.ndarray, dt: float, f_lo: float, f_hi: float) -> tuple[float, float]:
    """(frequency [Hz], damping ratio) of the least damped pole pair between f_lo and f_hi."""
    s = np.log(poles[np.abs(poles) > 1e-6].astype(complex)) / dt
    f = np.abs(s.imag) / (2 * math.pi)
    cand = s[(f > f_lo) & (f < f_hi)]
    worst = cand[np.argmin(-cand.real / np.abs(cand))]
    return abs(worst.imag) / (2 * math.pi), float(-worst.real / abs(worst))


def test_damping_of_the_motor_on_the_cable_is_what_physics_says_without_delay():
    """Limiting case: no delay, no other feedback. The motor on the held cable is J s^2 + (B_m + b) s + K:
    the damping ratio of its mode is (B_m + b) / (2 sqrt(K J)) (0.0061 -> 0.49 in sheath stick at b 40)."""
    p = SHEATH_STICK
    for b in (0.0, 40.0):
        cfg = _linear({**OLD_LOOP, "ki_1_s": 0.0, "inertia_comp_kg_m2": 0.0, "deflection_damping_Nms_rad": b})
        _, zeta = _mode(closed_loop_poles(cfg, p, 0), cfg.dt_s, 1.0, 100.0)
        assert zeta == pytest.approx((0.5 + b) / (2 * math.sqrt(3300.0 * 0.51)), rel=0.02)


def test_damping_makes_torque_feedback_stable_in_the_delayed_sheath_stick():
    """With the 2-cycle delay, kp 1.25 alone drives the sheath-stick mode unstable (negative damping);
    with b 100 the same mode is well damped (damping ratio > 0.3). The compiled step against the
    physical plant does the same: growth as the dominant pole predicts without b, decay with it."""
    p = SHEATH_STICK
    cfg_b = _linear(SHIPPED_LINEAR)
    cfg_0 = _linear({**SHIPPED_LINEAR, "deflection_damping_Nms_rad": 0.0})
    f_0, zeta_0 = _mode(closed_loop_poles(cfg_0, p, 2), cfg_0.dt_s, 5.0, 60.0)
    f_b, zeta_b = _mode(closed_loop_poles(cfg_b, p, 2), cfg_b.dt_s, 5.0, 60.0)
    assert zeta_0 < 0.0 and zeta_b > 0.3, (f_0, zeta_0, f_b, zeta_b)
    rho = float(np.max(np.abs(closed_loop_poles(cfg_0, p, 2))))
    n_win = int(min(3000, max(100, round(math.log(20.0) / math.log(rho)))))
    v = _run_step_physical(cfg_0, p, 2, 500 + 2 * n_win)
    a_, b_ = (np.max(np.abs(v[500 + i * n_win:500 + (i + 1) * n_win])) for i in (0, 1))
    assert 1.0 / 3.0 < (b_ / a_) / rho ** n_win < 3.0 and b_ > 2.0 * a_
    v = _run_step_physical(cfg_b, p, 2, 3000)
    assert np.max(np.abs(v[-1000:])) < 0.01 * np.max(np.abs(v[:1000]))


@pytest.mark.parametrize("p", [PlantPoint(200.0, 0.51, 0.5, slip=True, link_stiffness_Nm_rad=0.945),
                               PlantPoint(300.0, 0.95, 0.5, slip=True, link_stiffness_Nm_rad=0.945)])
def test_shipped_loop_decays_in_slip_as_the_analysis_says(p):
    """In slip (link free, IMU at 400 Hz for the link's velocity) the compiled step with the shipped
    kp and damping decays, and the analysis says stable."""
    cfg = _linear(SHIPPED_LINEAR)
    assert float(np.max(np.abs(closed_loop_poles(cfg, p, 2)))) < 1.0
    v = _run_step_physical(cfg, p, 2, 8000)
    assert np.max(np.abs(v[-1000:])) < 0.2 * np.max(np.abs(v[:1000]))


@pytest.mark.parametrize("p", [PlantPoint(300.0, 0.95, 0.5, slip=True, link_stiffness_Nm_rad=0.945), SHEATH_STICK])
def test_shipped_feedback_with_lag_compensation_decays_as_the_analysis_says(p):
    """The shipped gains (kp 0.75, b 60, link 30 Hz led by its lag x J_c's link acceleration, J_c 0.2)
    at the points that limit them (slip, J_m +30 %; sheath stick): stable by the analysis, and the
    compiled step against the physical plant (IMU at 400 Hz, 2-cycle FIFO) decays."""
    cfg = _linear({"rest_gate_cutoff_hz": 0.0, "ki_1_s": 0.0, "output_torque_gain": 0.0, "kp": 0.75, "deflection_damping_Nms_rad": 60.0,
                   "deflection_link_cutoff_hz": 30.0, "deflection_link_lag_compensation": True,
                   "inertia_comp_kg_m2": 0.2})
    assert float(np.max(np.abs(closed_loop_poles(cfg, p, 2)))) < 1.0
    v = _run_step_physical(cfg, p, 2, 8000)
    assert np.max(np.abs(v[-1000:])) < 0.2 * np.max(np.abs(v[:1000]))


def test_no_braking_in_a_steady_motion_and_nothing_at_rest():
    """A steady motion (motor and link at the same speed, constant deflection) gets no damping
    torque: the command equals the one without the term. At rest (gyro noise inside the rest band,
    encoder velocity quantised noise) the shipped rest gate keeps kp and the damping off the
    command entirely: bit-identical to the loop without them. Once the joint moves, the damping
    acts on a deflection rate: a motor running 0.05 rad/s ahead of the link gets -b x 0.05 (faded in)."""
    def run(fb: dict, dq_m, dq_out, n: int = 3000, gyro: np.ndarray | None = None) -> np.ndarray:
        m = _quiet({"feedback": fb})
        ctl = Controller(ControllerConfig.from_mapping(m))
        r = ctl.record[0]
        out = np.zeros(n)
        for k in range(n):
            r["t_s"] = r["lc_t_s"] = r["imu_t_s"] = r["motor_t_s"] = k * 1e-3
            r["T_up_in_N"], r["T_lo_in_N"] = 150.0 + 1.0 / 0.08, 150.0 - 1.0 / 0.08     # tau_in 2 Nm
            r["T_up_out_N"] = r["T_lo_out_N"] = 150.0
            r["imu_new"] = 1 if k % 5 in (0, 3) else 0
            r["dq_m_rad_s"] = dq_m(k)
            r["dq_out_rad_s"] = dq_out(k) + (gyro[k] if gyro is not None else 0.0)
            out[k] = ctl.step()
        return out
    shipped = {"kp": 1.25, "deflection_damping_Nms_rad": 100.0, "rest_gate_cutoff_hz": 5.0, "ki_1_s": 0.0,
               "inertia_comp_kg_m2": 0.0, "motor_velocity": "drive"}     # a quantised 0x606C read as it is
    off = {**shipped, "deflection_damping_Nms_rad": 0.0}
    steady = (lambda k: 0.4, lambda k: 0.4)
    assert np.max(np.abs(run(shipped, *steady) - run(off, *steady))[500:]) < 1e-9
    rng = np.random.default_rng(5)
    gyro = rng.normal(0.0, 2e-3, 3000)
    quant = 2 * math.pi / 131072                     # one 0x606C unit at 2^17 increments/s per rev
    enc = rng.integers(-1, 2, 3000) * quant
    rest = (lambda k: enc[k], lambda k: 0.0)
    no_fb = {**off, "kp": 0.0}
    assert np.array_equal(run(shipped, *rest, gyro=gyro), run(no_fb, *rest, gyro=gyro))
    ahead = (lambda k: 0.45, lambda k: 0.4)
    d = run({**shipped, "kp": 0.0}, *ahead) - run({**off, "kp": 0.0}, *ahead)
    assert d[-1] == pytest.approx(-100.0 * 0.05, rel=1e-6)
    assert np.max(np.abs(np.diff(d))) < 0.1 * 100.0 * 0.05       # faded in, not a step


@pytest.mark.slow
def test_link_lag_compensation_is_the_steps_and_is_checked():
    """``deflection_link_lag_compensation``: the link's velocity in the damping is led by
    (1 / (2 pi f_l) + dt) x J_c's link acceleration. The analysis's path (H_l + lead A) is the step's
    to rounding; it needs the link source; and the start-up check sees what it costs, link-acceleration
    feedback like J_c: with kp 0.75 / b 60 and J_c 0.3 it misses the phase margin (43 deg, slip), with the
    shipped J_c 0.2 it meets both (PM 50 deg, GM 9.1 dB)."""
    from capstan.controller.law.feedback_config import deflection_link_lead_s
    from capstan.controller.law.loop_model import acceleration_filter
    from capstan.controller.law.stability import check_margins
    from capstan.models.common.errors import ConfigError
    cfg = _linear({**SHIPPED_LINEAR, "kp": 0.0, "deflection_link_cutoff_hz": 30.0,
                   "deflection_link_lag_compensation": True,
                   "motor_velocity": "drive"})   # open loop: an observer would see the command move the motor
    lead = deflection_link_lead_s(cfg)
    assert lead == pytest.approx(1.0 / (2 * math.pi * 30.0) + 1e-3)
    x = np.zeros(400)
    x[5] = 1e-2
    u = _pulse_run(cfg, "dq_out_rad_s", x)
    hl, a = deflection_link_filter(cfg), acceleration_filter(cfg)
    assert hl[0][0] == 0.0 and a[0][0] == 0.0          # the IMU hold's cycle, not there with the IMU every cycle
    want = 100.0 * (signal.lfilter(hl[0][1:], hl[1], x) + lead * signal.lfilter(a[0][1:], a[1], x))
    assert np.max(np.abs(u - want)) < 1e-9 * np.max(np.abs(u))
    on = {**PREV_JC, "deflection_link_cutoff_hz": 30.0, "deflection_link_lag_compensation": True, "acceleration_source": "link",
          "output_torque_gain": 0.0, "band_gain": 0.0,
          "motor_velocity": "drive"}     # the loop this was tuned on, before the band gain and the velocity observer
    with pytest.raises(ConfigError, match="phase margin"):
        check_margins(ControllerConfig.from_mapping({"feedback": {**on, "inertia_comp_kg_m2": 0.3}}))
    rep = check_margins(ControllerConfig.from_mapping({"feedback": {**on, "inertia_comp_kg_m2": 0.2}}))
    assert rep.ok and rep.worst_phase_margin_deg > 48.0 and rep.worst_gain_margin_dB > 8.0


@pytest.mark.slow
def test_start_up_check_covers_the_faded_gains():
    """kp and b fade to 0 at rest, so the loop at rest is the one without them. J_c 0.34 (link rate at
    150 Hz, no lag compensation) meets the margins with kp and b on (PM 49.9 deg, GM 9.1 dB) but not at
    rest (GM 5.7 dB, the free link's residual gravity mode in slip): refused, saying which fade fails."""
    from capstan.controller.law.stability import analyse, check_margins
    from capstan.models.common.errors import ConfigError
    m = {"feedback": {**PREV_JC, "inertia_comp_kg_m2": 0.34, "deflection_link_cutoff_hz": 150.0, "output_torque_gain": 0.0,
                      "deflection_link_lag_compensation": False}}
    rep = analyse(ControllerConfig.from_mapping(m))
    assert rep.all_stable and rep.worst_phase_margin_deg >= 45.0 and rep.worst_gain_margin_dB >= 6.0
    assert [f[0] for f in rep.faded] == [0.5, 0.0] and not rep.faded[1][3] and rep.faded[1][2] < 6.0
    with pytest.raises(ConfigError, match="faded to x0"):
        check_margins(ControllerConfig.from_mapping(m))
    m["feedback"]["rest_gate_cutoff_hz"] = 0.0          # always on: no fade, nothing else to check
    assert analyse(ControllerConfig.from_mapping(m)).faded == ()
