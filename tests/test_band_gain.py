"""The band gain on the tau_in error (``controller.feedback.band_gain``, ``band_low_hz``,
``band_high_hz``): loop gain in the strokes' band (0.3-2 Hz) without raising it at the sheath-stick
mode or at the free link's slow mode. The loop model's path against the compiled step, the error's
rejection against the analytic Butterworth band-pass, the start-up check on sets of it, the compiled
step in closed loop at the grid points that limit the shipped set, and nothing at rest."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from capstan.controller.law.config import ControllerConfig
from capstan.controller.law.core import Controller
from capstan.controller.law.loop_model import PlantPoint, band_filter, closed_loop_poles
from capstan.controller.law.stability import check_margins
from capstan.models.common.errors import ConfigError
from test_deflection_damping import _linear, _pulse_run
from test_torque_loop import OLD_LOOP, _run_step_physical

#: the band gain of the shipped loop (config/controller.yaml)
K_B = 2.5
BAND_HZ = (0.3, 2.0)
#: the shipped feedback as the linear loop the analysis has (no fade, no integral trim)
SHIPPED_LINEAR = {"kp": 0.75, "deflection_damping_Nms_rad": 60.0, "deflection_link_cutoff_hz": 30.0,
                  "deflection_link_lag_compensation": True, "inertia_comp_kg_m2": 0.2, "acceleration_source": "link",
                  "acceleration_cutoff_hz": 5.0, "link_inertia_comp_kg_m2": 0.0,
                  "rest_gate_cutoff_hz": 0.0, "ki_1_s": 0.0, "output_torque_gain": 0.0, "band_gain": K_B, "band_low_hz": BAND_HZ[0],
                  "band_high_hz": BAND_HZ[1]}


@pytest.mark.slow
def test_the_analysis_band_path_is_the_steps():
    """The compiled step's command for a torque-reference pulse is ``(1 + k_b BP) ref`` (kp 0, no
    damping) with BP its two biquads, to rounding; the loop model's ``k_b BP(z)`` (the biquads
    multiplied out) has their frequency response to 1e-5 of the band's gain (the expanded 4th-order
    polynomial, poles at |z| ~ 0.997, rounds to ~6e-7 of it; run as a direct-form filter it drifts by
    ~1e-5 of its output over 3000 cycles, so it is compared in frequency); and it passes nothing at DC (a reference step leaves only the feedforward)."""
    from capstan.controller.law.ldo import band_pass_sos
    cfg = _linear({**OLD_LOOP, "ki_1_s": 0.0, "inertia_comp_kg_m2": 0.0, "band_gain": 3.0})
    x = np.zeros(3000)
    x[5] = 0.5
    u = _pulse_run(cfg, "tau_out_ref_Nm", x)
    sos = band_pass_sos(*BAND_HZ, cfg.dt_s)
    sos6 = np.column_stack((sos[:, :3], np.ones(2), sos[:, 3:]))
    want = x + 3.0 * signal.sosfilt(sos6, x)
    assert np.max(np.abs(u - want)) < 1e-12
    f = np.geomspace(0.01, 499.0, 2000)
    _, h_sos = signal.sosfreqz(sos6, worN=f, fs=1.0 / cfg.dt_s)
    bb = band_filter(cfg)
    z = np.exp(-2j * np.pi * f * cfg.dt_s)
    h_lm = np.polyval(bb[0][::-1], z) / np.polyval(bb[1][::-1], z)
    assert np.max(np.abs(h_lm - 3.0 * h_sos)) < 1e-5 * 3.0      # 6e-7 of the peak: the expansion's rounding
    step = np.concatenate((np.zeros(5), np.full(20000, 0.5)))
    u = _pulse_run(cfg, "tau_out_ref_Nm", step)
    assert abs(u[-1] - 0.5) < 1e-3 * 0.5


def _butterworth_band_gain(f_hz: float, lo: float, hi: float) -> complex:
    """The analog 4th-order Butterworth band-pass lo-hi at f (the low-pass prototype 1 / (s^2 + sqrt2 s + 1)
    at s -> (s^2 + w0^2) / (s B)), independent of scipy's design."""
    w, w0sq, bw = 2 * math.pi * f_hz, (2 * math.pi) ** 2 * lo * hi, 2 * math.pi * (hi - lo)
    s = 1j * w
    p = (s * s + w0sq) / (s * bw)
    return 1.0 / (p * p + math.sqrt(2.0) * p + 1.0)


@pytest.mark.parametrize("f_hz", [0.02, math.sqrt(BAND_HZ[0] * BAND_HZ[1]), 1.6, 20.0])
def test_error_rejection_is_one_over_one_plus_kp_plus_the_band(f_hz):
    """Limiting case: the motor sets tau_in directly (tau_in = u less a disturbance d, one cycle
    later), the compiled step with kp 0.75 and the shipped k_b 2.5 over 0.3-2 Hz. The error's amplitude
    for a sinusoidal d is |d| / |1 + kp + k_b BP(f)| with BP the analytic Butterworth band-pass:
    1 / (1 + kp) at DC and far above the band, 1 / (1 + kp + k_b) at its centre (0.77 Hz): 2.4x less."""
    m = {**OLD_LOOP, "kp": 0.75, "ki_1_s": 0.0, "inertia_comp_kg_m2": 0.0, "band_gain": K_B}
    cfg = _linear(m)
    ctl = Controller(cfg)
    r = ctl.record[0]
    n_per = int(round(1.0 / (f_hz * cfg.dt_s)))
    n = max(6 * n_per, 4000) if f_hz > 0.1 else 3 * n_per
    e = np.zeros(n)
    u = 0.0
    for k in range(n):
        tau = u - 0.1 * math.sin(2 * math.pi * f_hz * k * cfg.dt_s)
        r["t_s"] = r["lc_t_s"] = r["imu_t_s"] = r["motor_t_s"] = k * cfg.dt_s
        r["T_up_in_N"], r["T_lo_in_N"] = 150.0 + tau / 0.08, 150.0 - tau / 0.08
        r["T_up_out_N"] = r["T_lo_out_N"] = 150.0
        r["imu_new"] = 1
        u = ctl.step()
        e[k] = r["err_Nm"]
    tail = e[-n_per:] if f_hz > 0.1 else e[-n_per:]
    amp = 0.5 * (np.max(tail) - np.min(tail))
    want = 0.1 / abs(1.0 + 0.75 + K_B * _butterworth_band_gain(f_hz, *BAND_HZ))
    assert amp == pytest.approx(want, rel=0.03)


@pytest.mark.slow
def test_start_up_check_on_band_gains():
    """k_b 2.5 (shipped) meets PM >= 45 deg / GM >= 6 dB with the fade; k_b 6 is refused (unstable
    at 0.2 Hz in partial sheath stick: the band's gain meets the overdamped motor-on-cable pole with
    its lag), and a band down at 0.05-0.2 Hz with k_b 4 is refused too (unstable at 0.1 Hz: there the
    band acts as an integral would)."""
    rep = check_margins(ControllerConfig.from_mapping({"feedback": {"band_gain": K_B}}))
    assert rep.ok and rep.worst_phase_margin_deg >= 45.0 and rep.worst_gain_margin_dB >= 6.0
    for bad in ({"band_gain": 6.0}, {"band_gain": 4.0, "band_low_hz": 0.05, "band_high_hz": 0.2}):
        with pytest.raises(ConfigError, match="controller.feedback"):
            check_margins(ControllerConfig.from_mapping({"feedback": bad}))
    with pytest.raises(ConfigError, match="band_high_hz"):
        ControllerConfig.from_mapping({"feedback": {"band_low_hz": 2.0, "band_high_hz": 1.0}})
    with pytest.raises(ConfigError, match="band_gain"):
        ControllerConfig.from_mapping({"feedback": {"band_gain": -1.0}})


@pytest.mark.parametrize("p", [PlantPoint(200.0, 0.511, 0.5, slip=True, link_stiffness_Nm_rad=0.945),
                               PlantPoint(300.0, 0.949, 0.5), PlantPoint(3300.0, 0.511, 0.5)],
                         ids=["slip-K200-J-30", "stick-K300-J+30", "sheath-stick-J-30"])
def test_shipped_band_gain_decays_at_its_limiting_points_in_the_compiled_step(p):
    """The shipped loop with the band gain at the grid points that limit it (slip gain margin, the
    stick mode the band's lag meets, sheath stick): stable by the analysis, and the compiled step
    closed on the physical plant (IMU at 400 Hz, 2-cycle FIFO) decays."""
    cfg = _linear(SHIPPED_LINEAR)
    assert float(np.max(np.abs(closed_loop_poles(cfg, p, 2)))) < 1.0
    v = _run_step_physical(cfg, p, 2, 12000)
    assert np.max(np.abs(v[-1000:])) < 0.2 * np.max(np.abs(v[:1000]))


def test_nothing_at_rest():
    """At rest (gyro noise inside the rest band, load-cell noise on tau_in) the fade keeps the band
    gain off the command: bit-identical to k_b 0."""
    def run(kb: float) -> np.ndarray:
        ctl = Controller(ControllerConfig.from_mapping({"feedback": {"band_gain": kb}, "gravity": {"enabled": False},
                                                        "feedforward": {"enabled": False}}))
        r = ctl.record[0]
        rng = np.random.default_rng(7)
        out = np.zeros(3000)
        for k in range(3000):
            r["t_s"] = r["lc_t_s"] = r["imu_t_s"] = r["motor_t_s"] = k * 1e-3
            r["T_up_in_N"], r["T_lo_in_N"] = 150.0 + rng.normal(0, 0.3), 150.0 + rng.normal(0, 0.3)
            r["T_up_out_N"] = r["T_lo_out_N"] = 150.0
            r["imu_new"] = 1 if k % 5 in (0, 3) else 0
            r["dq_out_rad_s"] = rng.normal(0.0, 2e-3)
            out[k] = ctl.step()
        return out
    assert np.array_equal(run(K_B), run(0.0))
