"""Discrete LDO filters against their continuous designs (scipy.signal as the oracle),
and the observer removing a step disturbance on the exactly discretized nominal plant."""

from __future__ import annotations


import numpy as np
import pytest
from scipy import signal

from capstan.controller.law.config import ControllerConfig
from capstan.controller.law.core import Controller
from capstan.controller.law.ldo import derivative_filter_coefficients, q_filter_coefficients, qpinv_filter_coefficients

DT = 1e-3
F_HZ = np.linspace(0.05, 100.0, 2000)


def _compare(b, a, num_c, den_c):
    w = 2 * np.pi * F_HZ
    hc = signal.freqs(num_c, den_c, w)[1]
    hd = signal.freqz(b, a, worN=w * DT)[1]
    mag_err = np.max(np.abs(np.abs(hd) / np.abs(hc) - 1.0))
    ph_err = np.max(np.abs(np.angle(hd / hc, deg=True)))
    return mag_err, ph_err


@pytest.mark.parametrize("cutoff_hz", [3.0, 10.0, 20.0, 40.0])
def test_q_matches_continuous_butterworth(cutoff_hz):
    b, a = q_filter_coefficients(cutoff_hz, DT)
    wc = 2 * np.pi * cutoff_hz
    num_c, den_c = signal.butter(2, wc, analog=True)
    mag_err, ph_err = _compare(b, a, num_c, den_c)
    assert mag_err < 0.01 and ph_err < 2.0, (mag_err, ph_err)
    assert np.sum(b) == pytest.approx(np.sum(a), rel=1e-12)   # unit DC gain


@pytest.mark.parametrize("cutoff_hz", [3.0, 10.0, 20.0, 40.0])
@pytest.mark.parametrize("k_c, j_m, b_m", [(240.0, 0.73, 0.5), (280.0, 0.73, 0.0), (240.0, 0.5, 5.0)])
def test_q_pinv_matches_continuous(cutoff_hz, k_c, j_m, b_m):
    b, a = qpinv_filter_coefficients(cutoff_hz, DT, k_c, j_m, b_m)
    num_q, den_q = signal.butter(2, 2 * np.pi * cutoff_hz, analog=True)
    num_c = np.polymul(num_q, [j_m / k_c, b_m / k_c, 1.0])
    mag_err, ph_err = _compare(b, a, num_c, den_q)
    assert mag_err < 0.01 and ph_err < 2.0, (mag_err, ph_err)
    # Q and Q P^-1 share the poles, so d_hat's two paths are consistent
    assert np.allclose(a, q_filter_coefficients(cutoff_hz, DT)[1])


def test_derivative_filter_matches_continuous():
    kd, fd = 0.05, 40.0
    b0, a1 = derivative_filter_coefficients(kd, fd, DT)
    wd = 2 * np.pi * fd
    f = np.linspace(0.1, 20.0, 200)
    hc = signal.freqs([kd * wd, 0.0], [1.0, wd], 2 * np.pi * f)[1]
    hd = signal.freqz([b0, -b0], [1.0, a1], worN=2 * np.pi * f * DT)[1]
    assert np.max(np.abs(np.abs(hd) / np.abs(hc) - 1)) < 0.01
    assert np.max(np.abs(np.angle(hd / hc, deg=True))) < 2.0


def test_bad_cutoff_is_rejected():
    with pytest.raises(ValueError):
        q_filter_coefficients(300.0, DT)


def _nominal_plant_zoh(k_c, j_m, b_m):
    """Exact ZOH discretization of J q'' + B q' + K q = u, tau_in = K q (output held)."""
    a = np.array([[0.0, 1.0], [-k_c / j_m, -b_m / j_m]])
    b = np.array([[0.0], [1.0 / j_m]])
    c = np.array([[k_c, 0.0]])
    ad, bd, cd, _, _ = signal.cont2discrete((a, b, c, np.zeros((1, 1))), DT, method="zoh")
    return ad, bd[:, 0], cd[0]


def _run_nominal(ctl, k_c=240.0, j_m=0.73, b_m=0.5, d_Nm=2.0, t_dist_s=0.1, t_end_s=1.5):
    ad, bd, cd = _nominal_plant_zoh(k_c, j_m, b_m)
    x = np.zeros(2)
    rec = ctl.record[0]
    r_in = ctl.cfg.plant.r_in_m
    n = int(round(t_end_s / DT))
    out = np.zeros((n, 3))
    for k in range(n):
        t = k * DT
        tau_in = float(cd @ x)
        rec["t_s"] = t
        rec["lc_t_s"] = rec["imu_t_s"] = rec["motor_t_s"] = t
        rec["T_up_in_N"] = rec["T_up_out_N"] = 150.0 + tau_in / (2 * r_in)
        rec["T_lo_in_N"] = rec["T_lo_out_N"] = 150.0 - tau_in / (2 * r_in)
        rec["imu_new"] = 1
        tau_m = ctl.step()
        d = d_Nm if t >= t_dist_s else 0.0
        out[k] = (t, tau_in, float(rec["d_hat_Nm"]) + d)
        x = ad @ x + bd * (tau_m + d)
    assert not ctl.faulted
    return out


def _ctl(loop="ldo", cutoff_hz=10.0, **extra):
    m = {"torque_loop": loop, "ldo": {"q_cutoff_hz": cutoff_hz}, "gravity": {"enabled": False},
         "feedforward": {"enabled": False}, "feedback": {"kp": 5.0, "kd_s": 0.05, "derivative_cutoff_hz": 40.0, "ki_1_s": 20.0,   # lock-step gains
                      "deflection_damping_Nms_rad": 0.0, "rest_gate_cutoff_hz": 0.0, "band_gain": 0.0, "output_torque_gain": 0.0}}
    m.update(extra)
    return Controller(ControllerConfig.from_mapping(m))


@pytest.mark.parametrize("cutoff_hz", [10.0, 20.0])
def test_observer_removes_step_disturbance_within_5_over_wc(cutoff_hz):
    d = 2.0
    out = _run_nominal(_ctl(cutoff_hz=cutoff_hz), d_Nm=d)
    wc = 2 * np.pi * cutoff_hz
    after = out[out[:, 0] >= 0.1 + 5.0 / wc]
    # residual disturbance d + d_hat acting on the plant
    assert np.max(np.abs(after[:, 2])) < 0.05 * d
    # and tau_in (reference 0) settles back: no steady offset
    assert abs(out[-1, 1]) < 0.01 * d


def test_without_observer_a_p_loop_keeps_an_offset():
    """Contrast: P(D) alone leaves the static offset d / (1 + kp) of a motor disturbance."""
    d = 2.0
    out = _run_nominal(_ctl(loop="pid", feedback={"kp": 5.0, "kd_s": 0.05, "ki_1_s": 0.0,
                                                   "deflection_damping_Nms_rad": 0.0, "rest_gate_cutoff_hz": 0.0, "band_gain": 0.0, "output_torque_gain": 0.0}), d_Nm=d)
    kp = 5.0
    assert out[-1, 1] == pytest.approx(d / (1 + kp), rel=0.02)
