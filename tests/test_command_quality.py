"""Command-quality figures of the daemon's stats, checked on signals with known answers,
and the gravity angle's complementary filter."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capstan.controller.law.config import ControllerConfig
from capstan.controller.law.core import Controller
from capstan.controller.runtime.command_quality import CommandQuality

DT = 1e-3


def _feed(cq: CommandQuality, x: np.ndarray, tin: np.ndarray | None = None) -> None:
    for k, v in enumerate(x):
        cq.add(float(v), 0.0 if tin is None else float(tin[k]))


def test_buzz_is_high_frequency_and_a_slow_push_is_not():
    t = np.arange(1000) * DT
    buzz, push = CommandQuality(1000, DT, 2.0), CommandQuality(1000, DT, 2.0)
    _feed(buzz, 2.5 * np.sin(2 * math.pi * 48.0 * t))
    _feed(push, 0.5 * np.sin(2 * math.pi * 0.3 * t) + 0.2)
    b, p = buzz.take_window(), push.take_window()
    assert b.cmd_hf_share > 0.99 and p.cmd_hf_share < 0.01
    assert b.cmd_std_Nm == pytest.approx(2.5 / math.sqrt(2), rel=0.01)
    # rms change of a sine: A * 2 sin(pi f dt) / sqrt(2)
    assert b.cmd_change_rms_Nm == pytest.approx(2.5 * 2 * math.sin(math.pi * 48 * DT) / math.sqrt(2), rel=0.01)


def test_rate_limit_hits_counted_and_not_across_a_break():
    cq = CommandQuality(100, DT, 2.0)
    _feed(cq, [0.0, 2.0, 4.0, 5.0, 3.0, 1.0])       # 4 steps of 2 Nm (the clamp), one of 1
    cq.break_sequence()
    _feed(cq, [10.0, 10.5])                          # a jump after a break is no hit
    r = cq.take_window()
    assert r.rate_limit_hits == 4


def test_run_report_pools_windows():
    cq = CommandQuality(500, DT, 0.0)
    rng = np.random.default_rng(0)
    x = rng.normal(0.0, 0.1, 1500)
    tin = rng.normal(0.0, 0.02, 1500)
    for i in range(3):
        _feed(cq, x[500 * i:500 * (i + 1)], tin[500 * i:500 * (i + 1)])
        cq.take_window()
    r = cq.run_report()
    assert r.cycles == 1500
    assert r.cmd_std_Nm == pytest.approx(np.std(x), rel=1e-9)
    assert r.tau_in_std_Nm == pytest.approx(np.std(tin), rel=1e-9)
    assert 0.9 < r.cmd_hf_share < 1.0                 # white noise: 96 % of the band above 20 Hz


def _gravity(ctl: Controller, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
    rec = ctl.record[0]
    out = np.zeros(len(q))
    for k in range(len(q)):
        rec["t_s"] = rec["lc_t_s"] = rec["imu_t_s"] = rec["motor_t_s"] = k * DT
        rec["T_up_in_N"] = rec["T_up_out_N"] = rec["T_lo_out_N"] = rec["T_lo_in_N"] = 150.0
        rec["q_out_rad"], rec["dq_out_rad_s"], rec["imu_new"] = q[k], dq[k], 1
        ctl.step()
        out[k] = rec["tau_g_Nm"]
    return out


def test_gravity_angle_follows_motion_without_lag_and_drops_angle_noise():
    """The complementary filter: on a 1 rad/s ramp the gravity torque has no lag (a 2 Hz
    low-pass would lag 80 ms, 0.08 rad); at rest 5e-4 rad of angle noise leaves < 20 %."""
    m = {"feedforward": {"enabled": False}, "gravity": {"enabled": True, "m_g_l_Nm": 3.78}}
    n = 2000
    t = np.arange(n) * DT
    q = 0.2 + 1.0 * t
    tg = _gravity(Controller(ControllerConfig.from_mapping(m)), q, np.ones(n))
    assert np.max(np.abs(tg[1000:] - 3.78 * np.sin(q[1000:]))) < 1e-6     # after the start transient
    rng = np.random.default_rng(1)
    noisy = 0.3 + rng.normal(0.0, 5e-4, n)
    rate = rng.normal(0.0, 2e-3, n)
    blended = _gravity(Controller(ControllerConfig.from_mapping(m)), noisy, rate)
    raw = _gravity(Controller(ControllerConfig.from_mapping({**m, "filters": {"q_out_blend_hz": 0.0}})), noisy, rate)
    assert np.std(blended[500:]) < 0.2 * np.std(raw[500:])
