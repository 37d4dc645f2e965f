"""The controller closed around the simulated rig (distributed plant, motor input,
testbed output), stepping 1 ms lock-step with the rig's noisy sensors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capstan.controller.law.config import ControllerConfig
from capstan.controller.law.core import Controller
from capstan.controller.law.records import FaultBits
from capstan.models.plant.config import plant_from_mapping
from capstan.models.plant.rig import SensorNoise, SimulatedRig
from capstan.tools.experiments.interaction import LockStep

AMP_NM = 3.0
F_HZ = 1.0


def _setup(loop="ldo", k_c=240.0, j_m=0.73):
    spec = plant_from_mapping({
        "transmission": {"stiffness_Nm_rad": k_c}, "routing": {"length_m": 1.379, "theta_rad": 3.0},
        "pretension": {"T0_N": 150.0}, "output": {"mode": "testbed", "k_out_Nm_rad": 20.0, "b_out_Nms_rad": 2.0},
        "input": {"mode": "motor", "motor_inertia_kg_m2": j_m}})
    rig = SimulatedRig(spec, SensorNoise(), seed=1)
    # the controller keeps its nominal plant (K_c = 240, J_m = 0.73) whatever the rig has
    # the lock-step gains of the paper's design (the shipped defaults are the delay-robust ones)
    ctl = Controller(ControllerConfig.from_mapping({"torque_loop": loop, "gravity": {"enabled": False},
                                                   "feedback": {"kp": 5.0, "kd_s": 0.05, "derivative_cutoff_hz": 40.0, "ki_1_s": 20.0,
                                                                "output_torque_gain": 0.0},
                                                   "feedforward": {"enabled": False}}))
    return LockStep(ctl, rig)


def _track(ls, duration_s=4.0, tail_zero_s=0.0):
    n = int(round((duration_s + tail_zero_s) * 1000))
    t = np.zeros(n)
    tau_in = np.zeros(n)
    for k in range(n):
        t[k] = ls.rig.t_s
        ref = AMP_NM * math.sin(2 * math.pi * F_HZ * t[k]) if t[k] < duration_s else 0.0
        ls.cycle(0.0, ref)
        tau_in[k] = ls.rig.model.tau_in_Nm          # the true input torque
    return t, tau_in


def _amplitude_ratio(t, y, t0, t1):
    sel = (t >= t0) & (t < t1)
    m = np.column_stack([np.sin(2 * np.pi * F_HZ * t[sel]), np.cos(2 * np.pi * F_HZ * t[sel]), np.ones(sel.sum())])
    c = np.linalg.lstsq(m, y[sel], rcond=None)[0]
    return math.hypot(c[0], c[1]) / AMP_NM


#: measured 2026-11-28 with the motor-velocity observer (the default) on realistic devices: with J_m +30 % the
#: 1 Hz amplitude ratio is 1.089 (K_c 240) and 1.104 (K_c 280) against the bar's +-5 % (with the drive's exact
#: velocity it was 1.003): the observer's model inertia (0.82 J_m nominal) lags a motor 30 % heavier
J_HEAVY_SHORT = "J_m +30 %: 1 Hz amplitude ratio 1.089 / 1.104 with the velocity observer (bar 0.95-1.05)"


@pytest.mark.parametrize("k_c", [240.0, 280.0])
@pytest.mark.parametrize("j_scale", [0.7, 1.0, pytest.param(1.3, marks=pytest.mark.xfail(strict=True,
                                                                                         reason=J_HEAVY_SHORT))])
def test_ldo_tracks_1hz_reference_and_is_stable_over_plant_range(k_c, j_scale):
    ls = _setup("ldo", k_c, 0.73 * j_scale)
    t, tau_in = _track(ls, 4.0, tail_zero_s=1.0)
    assert not ls.ctl.faulted, ls.ctl.fault_bits
    ratio = _amplitude_ratio(t, tau_in, 2.0, 4.0)
    assert abs(ratio - 1.0) < 0.05, ratio
    # stable: after the reference drops to zero the torque settles, no growing oscillation
    tail = tau_in[t >= 4.5]
    assert np.max(np.abs(tail)) < 0.1 * AMP_NM, np.max(np.abs(tail))


def test_ldo_beats_pid_on_tracking():
    """The observer cancels the moving output's reaction the P(I)D loop has to fight."""
    t, y_ldo = _track(_setup("ldo"))
    t, y_pid = _track(_setup("pid"))
    e_ldo = abs(_amplitude_ratio(t, y_ldo, 2.0, 4.0) - 1.0)
    e_pid = abs(_amplitude_ratio(t, y_pid, 2.0, 4.0) - 1.0)
    assert e_ldo < 0.5 * e_pid


def test_nan_load_cell_zeroes_command_within_one_step_in_the_loop():
    ls = _setup()
    _track(ls, 0.5)
    assert ls.ctl.record[0]["tau_m_cmd_Nm"] != 0.0
    ls.write_measurements(1.0)
    ls.ctl.record[0]["T_lo_in_N"] = math.nan
    assert ls.ctl.step() == 0.0
    assert ls.ctl.fault_bits & FaultBits.NONFINITE_INPUT


def test_stale_imu_zeroes_command_within_one_step_in_the_loop():
    ls = _setup()
    _track(ls, 0.5)
    t_last_imu = float(ls.ctl.record[0]["imu_t_s"])
    cmds = []
    for _ in range(20):                     # IMU stream stops: imu_t_s frozen
        ls.write_measurements(1.0)
        ls.ctl.record[0]["imu_t_s"] = t_last_imu
        ls.ctl.record[0]["imu_new"] = 0
        cmds.append((float(ls.ctl.record[0]["t_s"]) - t_last_imu, ls.ctl.step()))
        ls.rig.step(cmds[-1][1])
    for age, cmd in cmds:
        if age > 0.010 + 1e-9:
            assert cmd == 0.0
        elif age < 0.010 - 1e-9:
            assert cmd != 0.0
    assert ls.ctl.fault_bits == FaultBits.STALE_IMU
