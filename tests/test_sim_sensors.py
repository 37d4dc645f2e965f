"""The simulated rig's device models against their physics and specs
(:mod:`capstan.models.plant.sensors`, ``drive_feedback``, ``command_path``)."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from capstan.drivers.serial.xsens import twist_angle_rad
from capstan.models.common.errors import ConfigError
from capstan.models.plant.command_path import CommandPath, CommandTiming
from capstan.models.plant.drive_feedback import RAD_S_PER_RPM, DriveFeedback, DriveFeedbackSettings, VelocitySource
from capstan.models.plant.rig import SimulatedRig
from capstan.models.plant.sensors import DeviceSettings, ImuErrors, ImuModel, LoadCellErrors, LoadCellModel, Mistakes

from test_rig import LINK_PLANT as IDEAL_LINK_PLANT  # noqa: E402

#: the rig of test_rig.py with its devices left to each test (realistic when absent)
LINK_PLANT = {k: v for k, v in IDEAL_LINK_PLANT.items() if k != "sensors"}
CPR = 1 << 17
COUNT_RAD = 2 * math.pi / CPR
DT = 1e-3


def _torque(k: int) -> float:
    """A motor torque that moves the link back and forth through rest [Nm]."""
    return 4.0 * math.sin(2 * math.pi * 0.7 * k * DT) + 2.0


# ---- ideal devices: the former simulation, bit for bit ---------------------------------

def test_ideal_devices_reproduce_the_former_exact_rig_bit_for_bit():
    """The former rig: fixture tensions + N(0, 0.3) from default_rng(seed), IMU at 400 Hz with
    angle then rate draws from the same generator, position rounded to counts, exact velocity."""
    seed = 7
    rig = SimulatedRig.from_mapping({**LINK_PLANT, "seed": seed, "sensors": "ideal",
                                     "noise": {"rate_bias_rad_s": 0.003}})
    ref = np.random.default_rng(seed)
    imu_index = 0
    for k in range(600):
        rig.step(_torque(k))
        m = rig.model
        lc = rig.load_cells_N()
        assert np.array_equal(lc, np.asarray(m.fixture_tensions_N, dtype=float) + ref.normal(0.0, 0.3, 4))
        idx = int(math.floor(rig.t_s * 400.0 + 1e-9))
        is_new, q, dq = rig.imu_sample()
        assert is_new == (idx != imu_index)
        if is_new:
            imu_index = idx
            assert q == float(m.q_out_rad + ref.normal(0.0, 5e-4))
            assert dq == float(m.dq_out_rad_s + 0.003 + ref.normal(0.0, 2e-3))
        qm, dqm, tau = rig.motor_feedback()
        assert qm == round(m.q_in_rad * CPR / (2 * math.pi)) * 2 * math.pi / CPR
        assert dqm == m.dq_in_rad_s and tau == _torque(k)
    assert rig.devices.label.startswith("ideal")


# ---- the drive's velocity and position ------------------------------------------------

def _drive_run(settings: DriveFeedbackSettings, counts: int = CPR, n: int = 400):
    """Drive a trajectory with varying velocity through DriveFeedback; returns (q, dq, reported q, v)."""
    d = DriveFeedback(settings, counts)
    t = np.arange(n + 1) * DT
    q = 0.3 * np.sin(2 * math.pi * 1.3 * t) + 0.8 * t
    dq = 0.3 * 2 * math.pi * 1.3 * np.cos(2 * math.pi * 1.3 * t) + 0.8
    d.reset(q[0], dq[0])
    rq, rv = [d.position_rad], [d.velocity_rad_s]
    for k in range(1, n + 1):
        d.update(q[k], dq[k], DT)
        rq.append(d.position_rad)
        rv.append(d.velocity_rad_s)
    return q, dq, np.array(rq), np.array(rv)


@pytest.mark.parametrize("source", list(VelocitySource))
def test_drive_position_is_quantised_to_one_count(source):
    q, _, rq, _ = _drive_run(DriveFeedbackSettings(source))
    counts = rq / COUNT_RAD
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    assert np.max(np.abs(rq - q)) <= COUNT_RAD / 2 + 1e-12


def test_encoder_difference_is_the_count_difference_per_millisecond():
    _, dq, rq, rv = _drive_run(DriveFeedbackSettings(VelocitySource.ENCODER_DIFFERENCE))
    steps = rv[1:] * DT / COUNT_RAD                   # counts per cycle: whole numbers
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)
    np.testing.assert_allclose(rv[1:], np.diff(rq) / DT, rtol=1e-12)
    # one count per ms is 0.048 rad/s: the difference is within a count of the mean velocity
    assert np.max(np.abs(rv[1:] - 0.5 * (dq[1:] + dq[:-1]))) <= 2 * COUNT_RAD / DT


def test_whole_rpm_is_the_true_velocity_rounded_to_one_rpm():
    _, dq, _, rv = _drive_run(DriveFeedbackSettings(VelocitySource.WHOLE_RPM))
    rpm = rv / RAD_S_PER_RPM
    np.testing.assert_allclose(rpm, np.round(rpm), atol=1e-9)
    assert np.max(np.abs(rv - dq)) <= 0.5 * RAD_S_PER_RPM + 1e-12
    assert len(np.unique(np.round(rpm))) > 5           # it moves over several rpm


def test_vendor_velocity_is_the_difference_in_units_of_0x60A9():
    """Default unit 1 rpm (EDS 60A9h = 0x00B44700): the 1 ms count difference rounded to whole rpm."""
    _, _, rq, rv = _drive_run(DriveFeedbackSettings())
    rpm = rv / RAD_S_PER_RPM
    np.testing.assert_allclose(rpm, np.round(rpm), atol=1e-9)
    diff = np.diff(rq) / DT
    np.testing.assert_allclose(rv[1:], np.round(diff / RAD_S_PER_RPM) * RAD_S_PER_RPM, rtol=1e-12)
    # a finer unit (prefix 10^-3) keeps the difference to within 0.0005 rpm
    _, _, rq, rv = _drive_run(DriveFeedbackSettings(velocity_unit_rpm=1e-3))
    assert np.max(np.abs(rv[1:] - np.diff(rq) / DT)) <= 0.5e-3 * RAD_S_PER_RPM + 1e-12


def test_vendor_velocity_lags_half_a_cycle_and_its_filter_is_first_order():
    """Without quantisation: under constant acceleration the 1 ms difference is the velocity
    half a cycle earlier; with ``velocity_filter_hz`` a velocity step rises as 1 - exp(-2 pi f t)."""
    a = 50.0
    d = DriveFeedback(DriveFeedbackSettings(velocity_unit_rpm=1e-9), 0)
    d.reset(0.0, 0.0)
    for k in range(1, 100):
        t = k * DT
        d.update(0.5 * a * t * t, a * t, DT)
        assert d.velocity_rad_s == pytest.approx(a * (t - DT / 2), rel=1e-6)
    f = 20.0
    d = DriveFeedback(DriveFeedbackSettings(velocity_unit_rpm=1e-9, velocity_filter_hz=f), 0)
    d.reset(0.0, 0.0)
    v = 2.0
    for k in range(1, 60):
        d.update(v * k * DT, v, DT)
        assert d.velocity_rad_s == pytest.approx(v * (1 - math.exp(-2 * math.pi * f * k * DT)), rel=1e-6)


def test_rig_motor_feedback_is_the_drive_model_of_the_true_motor():
    rig = SimulatedRig.from_mapping({**LINK_PLANT, "sensors": {"drive": {"velocity": "whole_rpm"}}})
    for k in range(300):
        rig.step(_torque(k))
        q, dq, _ = rig.motor_feedback()
        assert abs(dq - rig.model.dq_in_rad_s) <= 0.5 * RAD_S_PER_RPM + 1e-12
        assert abs(dq / RAD_S_PER_RPM - round(dq / RAD_S_PER_RPM)) < 1e-9
        assert abs(q - rig.model.q_in_rad) <= COUNT_RAD / 2 + 1e-12


# ---- load cells -----------------------------------------------------------------------

def test_load_cell_scale_and_offset_errors_within_the_configured_bounds_and_seeded():
    e = LoadCellErrors(scale_error=0.004, offset_N=0.0, drift_N=0.0)
    true = np.array([120.0, 180.0, 150.0, 90.0])
    r = LoadCellModel(e, Mistakes(), seed=3).report_N(true, 0.0) / true
    assert np.all(np.abs(r - 1.0) <= 0.004) and np.ptp(r) > 0.0
    assert np.array_equal(LoadCellModel(e, Mistakes(), 3).scale, LoadCellModel(e, Mistakes(), 3).scale)
    assert not np.array_equal(LoadCellModel(e, Mistakes(), 3).scale, LoadCellModel(e, Mistakes(), 4).scale)
    e = LoadCellErrors(scale_error=0.0, offset_N=2.0, drift_N=0.0)
    off = LoadCellModel(e, Mistakes(), seed=3).report_N(true, 0.0) - true
    assert np.all(np.abs(off) <= 2.0) and np.max(np.abs(off)) > 0.5


def test_load_cell_drift_is_slow_and_bounded_by_drift_N():
    e = LoadCellErrors(scale_error=0.0, offset_N=0.0, drift_N=1.5, drift_period_s=600.0)
    cells = LoadCellModel(e, Mistakes(), seed=11)
    t = np.arange(0.0, 7200.0, 1.0)
    drift = np.array([cells.drift_N(x) for x in t])
    assert np.max(np.abs(drift)) <= 1.5 and np.max(np.abs(drift), axis=0).min() > 0.9 * 1.5
    # slow: within one second a channel moves at most 2 pi drift_N / period
    assert np.max(np.abs(np.diff(drift, axis=0))) <= 2 * math.pi * 1.5 / 600.0 * 1.0001


# ---- IMU ------------------------------------------------------------------------------

def test_misalignment_scales_the_rate_by_cos_and_leaks_sin_onto_the_normal_axis():
    """Checked against scipy's rotations: orientation Rz(q) Rx(alpha); the body rate of that
    motion and the twist the Xsens driver extracts (twist_angle_rad, not this model's code)."""
    alpha = 3.0
    imu = ImuModel(ImuErrors(gyro_bias_rad_s=0.0, misalignment_deg=alpha), Mistakes())
    mount = Rotation.from_euler("x", alpha, degrees=True)
    q, dq, h = 0.7, 1.3, 1e-6
    r0 = Rotation.from_euler("z", q) * mount
    r1 = Rotation.from_euler("z", q + dq * h) * mount
    w_body = (r0.inv() * r1).as_rotvec() / h              # body-frame rate
    x, y, z, w = r0.as_quat()
    assert imu.report(q, dq)[0] == pytest.approx(twist_angle_rad((w, x, y, z), 2), abs=1e-12)
    along, leak = imu.rate_vector_rad_s(dq)
    assert along == pytest.approx(w_body[2], rel=1e-6) and along == pytest.approx(dq * math.cos(math.radians(alpha)))
    assert abs(leak) == pytest.approx(np.hypot(w_body[0], w_body[1]), rel=1e-5)
    assert imu.report(q, dq)[1] == along


def test_rig_imu_reports_bias_and_misalignment():
    rig = SimulatedRig.from_mapping({**LINK_PLANT, "noise": {"angle_rad": 0.0, "rate_rad_s": 0.0},
                                     "sensors": {"imu": {"gyro_bias_rad_s": 0.002, "misalignment_deg": 20.0}}})
    seen = 0
    for k in range(400):
        rig.step(_torque(k))
        is_new, q, dq = rig.imu_sample()
        if is_new and abs(rig.model.dq_out_rad_s) > 0.05:
            seen += 1
            assert q == rig.model.q_out_rad
            assert dq == pytest.approx(rig.model.dq_out_rad_s * math.cos(math.radians(20.0)) + 0.002, abs=1e-12)
    assert seen > 20


# ---- command path ---------------------------------------------------------------------

def test_command_delay_is_one_to_three_cycles_with_the_configured_jitter():
    timing = CommandTiming(jitter_cycles=1, jitter_probability=0.05, loss_probability=0.0)
    path = CommandPath(timing, delay_cycles=2, seed=5)
    n = 100_000
    applied = np.array([path.push(float(k)) for k in range(n)])
    lag = np.arange(n)[10:] - applied[10:]
    assert set(np.unique(lag)) <= {1, 2, 3} and {1, 3} <= set(np.unique(lag))
    # binomial: 5 % of 1e5 = 5000 +- 69; 4 sigma
    assert abs(path.jittered - 5000) <= 4 * math.sqrt(n * 0.05 * 0.95)
    assert np.all(np.diff(applied) >= 0)                   # in order, as CAN delivers one COB-ID


def test_lost_commands_at_the_configured_rate_hold_the_previous_one():
    p = 0.002
    path = CommandPath(CommandTiming(jitter_cycles=0, jitter_probability=0.0, loss_probability=p), 2, seed=9)
    n = 200_000
    applied = np.array([path.push(float(k + 1)) for k in range(n)])
    never = n - 2 - len(np.unique(applied[2:]))
    assert never == path.lost
    assert abs(path.lost - n * p) <= 4 * math.sqrt(n * p * (1 - p))
    held = np.flatnonzero(np.diff(applied[2:]) == 0)       # a lost command: the previous one held
    assert len(held) == path.lost


def test_ideal_command_path_is_the_fixed_delay():
    path = CommandPath(CommandTiming.ideal(), 2)
    assert [path.push(float(k)) for k in range(1, 7)] == [0.0, 0.0, 1.0, 2.0, 3.0, 4.0]
    assert [CommandPath(CommandTiming.ideal(), 0).push(3.5)] == [3.5]


# ---- mistakes -------------------------------------------------------------------------

def test_mistakes_swap_scale_and_flip_what_the_rig_reports():
    m = Mistakes(load_cell_gain=(1.0, 2.0, 1.0, 1.0), load_cell_order=(3, 1, 2, 0), imu_sign=-1,
                 motor_direction=-1)
    ideal = SimulatedRig.from_mapping({**LINK_PLANT, "noise": {"tension_N": 0.0, "angle_rad": 0.0, "rate_rad_s": 0.0},
                                       "sensors": "ideal"})
    rig = SimulatedRig(ideal.spec, ideal.noise, devices=DeviceSettings.ideal().with_mistakes(m))
    for k in range(300):
        ideal.step(3.0)
        rig.step(3.0)
    f = np.asarray(rig.model.fixture_tensions_N, dtype=float)
    np.testing.assert_array_equal(rig.load_cells_N(), f[[3, 1, 2, 0]] * [1.0, 2.0, 1.0, 1.0])
    # motor direction flipped: +3 Nm turns the joint the other way, yet the drive reports
    # its own motion as positive
    assert rig.model.q_in_rad == pytest.approx(-ideal.model.q_in_rad, rel=1e-9) and ideal.model.q_in_rad > 0.01
    assert rig.motor_feedback()[0] > 0.01 and rig.motor_feedback()[2] == 3.0
    is_new, q, dq = rig.imu_sample()
    assert q == -rig.model.q_out_rad and q > 0.0
    wrong = SimulatedRig(ideal.spec, ideal.noise,
                         devices=DeviceSettings.ideal().with_mistakes(Mistakes(imu_axis_wrong=True)))
    for k in range(300):
        wrong.step(3.0)
    assert wrong.imu_sample()[1:] == (0.0, 0.0) and abs(wrong.model.q_out_rad) > 0.01


def test_sensors_config_presets_and_errors_name_the_key():
    assert DeviceSettings.from_config(None) == DeviceSettings.realistic()
    assert DeviceSettings.from_config("ideal") == DeviceSettings.ideal()
    d = DeviceSettings.from_config({"preset": "ideal", "mistakes": {"load_cell_order": [1, 0, 2, 3]}})
    assert d.drive.velocity == VelocitySource.EXACT and d.mistakes.load_cell_order == (1, 0, 2, 3)
    assert "mistakes" in d.label
    bad = [("exactish", "plant.sensors'"),
           ({"drive": {"velocity": "rpm"}}, "plant.sensors.drive.velocity"),
           ({"load_cells": {"scale_error": -0.1}}, "plant.sensors.load_cells.scale_error"),
           ({"command": {"loss_probability": 0.9}}, "plant.sensors.command.loss_probability"),
           ({"mistakes": {"load_cell_order": [0, 0, 1, 2]}}, "plant.sensors.mistakes.load_cell_order"),
           ({"mistakes": {"imu_sign": 0}}, "plant.sensors.mistakes.imu_sign"),
           ({"mistakes": {"load_cell_gain": [1, 1, 1]}}, "plant.sensors.mistakes.load_cell_gain"),
           ({"imu": {"bias": 1}}, "plant.sensors.imu.bias")]
    for value, key in bad:
        with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
            DeviceSettings.from_config(value)
    with pytest.raises(ConfigError, match=r"hil\.plant\.sensors\.mistakes\.motor_direction"):
        SimulatedRig.from_mapping({**LINK_PLANT, "sensors": {"mistakes": {"motor_direction": 2}}}, "hil.plant")
