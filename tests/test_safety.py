"""Safety stage: any fault zeroes the command in the same step and stays latched until
reset; clamps and rate limits; replay determinism; config errors name the key."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capstan.controller.law.config import ControllerConfig
from capstan.controller.law.core import Controller
from capstan.controller.law.records import FaultBits, RECORD_DTYPE, fault_names
from capstan.models.common.errors import ConfigError

DT = 1e-3
R_IN = 0.04


def _ctl(**extra):
    m = {"torque_loop": "ldo", "feedback": {"kp": 5.0, "kd_s": 0.05, "derivative_cutoff_hz": 40.0, "ki_1_s": 20.0}, "gravity": {"enabled": True, "m_g_l_Nm": 3.78},
         "feedforward": {"enabled": False}}
    m.update(extra)
    return Controller(ControllerConfig.from_mapping(m))


def _write(ctl, k, tau_in=3.78 * math.sin(0.5), q_out=0.5, dq_out=0.0, imu_age_s=0.0, lc_age_s=0.0, motor_age_s=0.0):
    rec = ctl.record[0]
    t = 10.0 + k * DT
    rec["cycle"] = k
    rec["t_s"] = t
    rec["T_up_in_N"] = rec["T_up_out_N"] = 150.0 + tau_in / (2 * R_IN)
    rec["T_lo_in_N"] = rec["T_lo_out_N"] = 150.0 - tau_in / (2 * R_IN)
    rec["lc_t_s"] = t - lc_age_s
    rec["q_out_rad"] = q_out
    rec["dq_out_rad_s"] = dq_out
    rec["imu_t_s"] = t - imu_age_s
    rec["imu_new"] = 1
    rec["motor_t_s"] = t - motor_age_s
    rec["q_m_rad"] = rec["dq_m_rad_s"] = rec["tau_m_meas_Nm"] = 0.0
    rec["ext_fault_bits"] = 0
    return rec


TAU_G = 3.78 * math.sin(0.5)


def _healthy(ctl, n=30):
    """Cycles with the measured torque already at the gravity reference (perfect tracking)."""
    tau = 0.0
    for k in range(n):
        _write(ctl, k, tau_in=TAU_G)
        tau = ctl.step()
    assert not ctl.faulted
    return tau, n


def test_healthy_run_tracks_the_gravity_reference_without_a_fault():
    # tau_in already equals the gravity reference with the motor at zero torque: the LDO
    # reads that as a disturbance holding the link (d_hat = -tau_g) and commands nothing
    ctl = _ctl()
    tau, _ = _healthy(ctl, 200)
    r = ctl.record[0]
    assert r["tau_g_Nm"] == pytest.approx(3.78 * math.sin(0.5))
    assert r["tau_in_des_Nm"] == pytest.approx(TAU_G) and r["d_hat_Nm"] == pytest.approx(-TAU_G)
    assert abs(tau) < 1e-9 and r["tau_m_cmd_Nm"] == tau and r["fault_bits"] == 0


@pytest.mark.parametrize("field", ["T_up_in_N", "q_out_rad", "dq_out_rad_s", "tau_m_meas_Nm", "t_s"])
def test_nan_input_zeroes_command_in_the_same_step_and_latches(field):
    ctl = _ctl()
    _, k = _healthy(ctl)
    rec = _write(ctl, k)
    rec[field] = math.nan
    assert ctl.step() == 0.0
    assert ctl.fault_bits & FaultBits.NONFINITE_INPUT
    assert rec["tau_m_cmd_Nm"] == 0.0 and rec["fault_bits"] == int(ctl.fault_bits)
    for j in range(k + 1, k + 20):           # healthy again: stays latched
        _write(ctl, j)
        assert ctl.step() == 0.0
    ctl.reset()
    _write(ctl, k + 20)
    ctl.step()
    assert not ctl.faulted


def test_stale_imu_beyond_10_ms_zeroes_command():
    ctl = _ctl()
    _, k = _healthy(ctl)
    _write(ctl, k, tau_in=TAU_G - 0.5, imu_age_s=0.009)     # a tracking error: a command to zero
    assert abs(ctl.step()) > 0.1 and not ctl.faulted
    _write(ctl, k + 1, tau_in=TAU_G - 0.5, imu_age_s=0.0105)
    assert ctl.step() == 0.0
    assert ctl.fault_bits == FaultBits.STALE_IMU
    assert fault_names(ctl.fault_bits) == "STALE_IMU"


@pytest.mark.parametrize("kw, bit", [({"lc_age_s": 0.006}, FaultBits.STALE_LOADCELL),
                                     ({"motor_age_s": 0.006}, FaultBits.STALE_MOTOR)])
def test_stale_loadcell_and_motor(kw, bit):
    ctl = _ctl()
    _, k = _healthy(ctl)
    _write(ctl, k, **kw)
    assert ctl.step() == 0.0 and ctl.fault_bits == bit


def test_external_fault_bits_latch():
    ctl = _ctl()
    _, k = _healthy(ctl)
    rec = _write(ctl, k)
    rec["ext_fault_bits"] = int(FaultBits.DRIVE_FAULT)
    assert ctl.step() == 0.0
    _write(ctl, k + 1)
    assert ctl.step() == 0.0 and ctl.fault_bits == FaultBits.DRIVE_FAULT


def test_torque_above_hard_limit_zeroes_command():
    # gravity model of 70 Nm at q = pi/2 demands beyond tau_fault_Nm = 60
    # raw angle (no complementary filter): the angle jumps without a rate, as a fault would
    ctl = _ctl(gravity={"m_g_l_Nm": 70.0}, safety={"dtau_fault_Nm_s": 1e6}, filters={"q_out_blend_hz": 0.0})
    _write(ctl, 0, q_out=0.0)
    ctl.step()
    _write(ctl, 1, q_out=math.pi / 2)
    assert ctl.step() == 0.0
    assert ctl.fault_bits & FaultBits.TORQUE_LIMIT


def test_demand_between_clamp_and_hard_limit_is_clamped_and_rate_limited():
    # 20 Nm demand: above the 15 Nm clamp, below the 60 Nm fault limit; 2 Nm/cycle rate clamp
    ctl = _ctl(gravity={"m_g_l_Nm": 20.0}, feedback={"kp": 0.0, "kd_s": 0.0})
    cmds = []
    for k in range(20):
        _write(ctl, k, q_out=math.pi / 2)
        cmds.append(ctl.step())
    assert not ctl.faulted
    assert np.all(np.abs(np.diff([0.0] + cmds)) <= 2.0 + 1e-12)
    assert cmds[-1] == pytest.approx(15.0)
    assert max(cmds) <= 15.0


def test_raw_demand_jump_trips_rate_fault():
    ctl = _ctl()
    _, k = _healthy(ctl)
    _write(ctl, k, tau_in=-10.0)      # a 12 Nm jump of the measured torque -> raw jumps > 60 Nm
    assert ctl.step() == 0.0
    assert ctl.fault_bits & FaultBits.TORQUE_RATE_LIMIT


def test_nonfinite_output_is_caught():
    # an infinite but finite-input demand cannot occur; simulate with a huge tension (finite)
    ctl = _ctl()
    _, k = _healthy(ctl)
    rec = _write(ctl, k)
    rec["T_up_in_N"] = 1e308
    rec["T_lo_in_N"] = -1e308             # r_in * (T_up - T_lo) overflows to inf
    assert ctl.step() == 0.0
    assert ctl.fault_bits & FaultBits.NONFINITE_OUTPUT


def test_replay_is_bit_identical():
    """Run on the nominal plant with noise, then replay the logged measurements."""
    rng = np.random.default_rng(1)
    log = np.zeros(300, dtype=RECORD_DTYPE)
    ctl = _ctl(feedforward={"enabled": True})
    k_c, j_m = 240.0, 0.73
    q_m, dq_m, tau = 0.0, 0.0, 0.0
    for k in range(300):
        rec = _write(ctl, k, tau_in=k_c * q_m + rng.normal(0, 0.02), q_out=0.3 + 0.001 * k,
                     dq_out=rng.normal(0, 0.02))
        rec["imu_new"] = 1 if k % 3 != 2 else 0
        tau = ctl.step()
        log[k] = ctl.record[0]
        dq_m += DT * (tau - k_c * q_m) / j_m            # semi-implicit Euler, output held
        q_m += DT * dq_m
    assert not ctl.faulted
    again = Controller(ControllerConfig.from_mapping(ctl.cfg.to_mapping()))
    for k in range(300):
        again.record[0] = log[k]
        assert again.step() == log[k]["tau_m_cmd_Nm"]        # exact equality
    assert np.array_equal(again.record["d_hat_Nm"], log[-1:]["d_hat_Nm"])


@pytest.mark.parametrize("mapping, key", [
    ({"ldo": {"q_cutoff_hz": -1.0}}, "controller.ldo.q_cutoff_hz"),
    ({"ldo": {"cutof_hz": 10.0}}, "controller.ldo.cutof_hz"),
    ({"torque_loop": "lqr"}, "controller.torque_loop"),
    ({"feedforward": {"placement": "output"}}, "controller.feedforward.placement"),
    ({"feedforward": {"zeta_s": 0.5}}, "controller.feedforward.zeta_s"),
    ({"safety": {"tau_fault_Nm": 5.0}}, "controller.safety.tau_fault_Nm"),
    ({"safety": {"tau_fault_Nm": 14.99}}, "controller.safety.tau_fault_Nm"),     # just below tau_max_Nm 15
    ({"safety": {"dtau_fault_Nm_s": 1999.0}}, "controller.safety.dtau_fault_Nm_s"),  # just below dtau_max 2000
    ({"safety": {"imu_timeout_s": "fast"}}, "controller.safety.imu_timeout_s"),
    ({"safety": {"command_quantum_Nm": 1e-5}}, "controller.safety.command_quantum_Nm"),   # not a power of two
    ({"safety": {"command_quantum_Nm": 0.01}}, "controller.safety.command_quantum_Nm"),   # coarser than 2**-10
    ({"feedforward": {"routing": {"length_m": 1.0}}}, "controller.feedforward.routing.theta_rad"),
])
def test_bad_config_names_the_key(mapping, key):
    with pytest.raises(ConfigError) as exc:
        ControllerConfig.from_mapping(mapping)
    assert exc.value.key == key


def test_fault_limits_equal_to_their_clamps_are_accepted():
    """The fault limits may sit at their clamps (>=), not below: the edge of the rule."""
    s = ControllerConfig.from_mapping({"safety": {"tau_fault_Nm": 15.0, "dtau_fault_Nm_s": 2000.0}})
    assert s.to_mapping()["safety"]["tau_fault_Nm"] == 15.0


def test_config_round_trip():
    cfg = ControllerConfig.from_mapping({"torque_loop": "pid", "feedforward": {
        "placement": "motor", "routing": {"curvature_profile": [[0.0, 1.0], [0.7, 6.0], [1.379, 1.0]]}}})
    assert ControllerConfig.from_mapping(cfg.to_mapping()) == cfg


def test_example_config_file_is_valid_and_matches_the_defaults():
    from pathlib import Path

    from capstan.models.common.config_tools import load_yaml

    path = Path(__file__).resolve().parents[1] / "config" / "controller.yaml"
    cfg = ControllerConfig.from_mapping(load_yaml(path)["controller"])
    assert cfg == ControllerConfig.from_mapping({})


def test_command_is_on_its_power_of_two_grid_within_both_limits():
    """The command is a multiple of COMMAND_QUANTUM_NM, at most half a quantum from the
    clamped and rate-limited demand, and never beyond either limit, also for limits that
    are not multiples of the quantum (the nearest multiple is then stepped back inside)."""
    from capstan.controller.law.safety import COMMAND_QUANTUM_NM, limit_command_Nm
    q = COMMAND_QUANTUM_NM
    assert math.frexp(q)[0] == 0.5 and q <= 1e-3 / 50      # far below the drive's 1 per mille of 20 Nm
    rng = np.random.default_rng(3)
    for _ in range(2000):
        tau_max = float(rng.choice([15.0, 12.3456789, 0.1 + rng.uniform()]))
        step = float(rng.choice([2.0, 0.0123456, rng.uniform(1e-3, 1.0)]))
        prev = float(np.round(rng.uniform(-tau_max, tau_max) / q) * q)
        raw = float(rng.uniform(-2.0 * tau_max, 2.0 * tau_max))
        cmd = limit_command_Nm(raw, prev, tau_max, step)
        want = min(max(min(max(raw, -tau_max), tau_max), prev - step), prev + step)
        assert cmd / q == round(cmd / q)                            # on the grid, exactly
        assert abs(cmd - want) <= q                                 # moved by less than a quantum
        assert abs(cmd) <= tau_max and abs(cmd - prev) <= step      # inside both limits
        if -tau_max + q < want < tau_max - q and abs(want - prev) < step - q:
            assert abs(cmd - want) <= q / 2                         # away from limits: nearest
    # the grid is the same in any order of operations: a multiple stays itself
    assert limit_command_Nm(3 * q, 0.0, 15.0, 2.0) == 3 * q
    assert limit_command_Nm(-0.5 * q * 1.0001, 0.0, 15.0, 2.0) == -q
