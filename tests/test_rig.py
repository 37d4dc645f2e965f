"""The simulated rig: sensor signals against the plant's physics and the sensor specs."""

import math

import numpy as np
import pytest

from capstan.models.common.errors import ConfigError
from capstan.models.plant.rig import SensorNoise, SimulatedRig

LINK_PLANT = {
    "transmission": {"n_nodes": 4},
    "routing": {"length_m": 1.379, "theta_rad": 2.0},
    "pretension": {"T0_N": 150.0},
    "input": {"mode": "motor"},
    "output": {"mode": "link"},
    # physics and noise specs against the true state: the exact devices (the realistic ones
    # are checked against their own specs in test_sim_sensors.py)
    "sensors": "ideal",
}


def test_link_hanging_at_rest_stays_at_rest_and_load_cells_read_pretension():
    rig = SimulatedRig.from_mapping({**LINK_PLANT, "noise": {"tension_N": 0.0}})
    # pretension applied at the fixtures: every fixture reads the boundary pretension
    np.testing.assert_allclose(rig.load_cells_N(), 150.0, rtol=1e-12)
    for _ in range(200):
        rig.step(0.0)
    assert abs(rig.model.q_out_rad) < 1e-6
    # the capstan field sits at the edge of the friction cone; the smooth Coulomb law (13)
    # lets it creep slightly (p = 100 regularization), symmetrically in both cables
    f = rig.load_cells_N()
    np.testing.assert_allclose(f, 150.0, rtol=1e-2)
    assert abs(f[0] - f[3]) < 1e-9 and abs(f[1] - f[2]) < 1e-9


def test_imu_produces_400_samples_per_second_with_configured_noise():
    rig = SimulatedRig.from_mapping({**LINK_PLANT, "noise": {"angle_rad": 1e-3, "rate_rad_s": 0.0}, "seed": 3})
    new, qs = 0, []
    for _ in range(1000):
        rig.step(0.0)
        is_new, q, dq = rig.imu_sample()
        if is_new:
            new += 1
            qs.append(q - rig.model.q_out_rad)
        assert dq == pytest.approx(rig.model.dq_out_rad_s, abs=1e-12) or not is_new
    assert new == 400
    assert np.std(qs) == pytest.approx(1e-3, rel=0.15)


def test_gravity_hold_torque_keeps_raised_link_still():
    """A motor torque equal to the gravity torque at the link angle holds the link (statics)."""
    rig = SimulatedRig.from_mapping({**LINK_PLANT, "noise": {"tension_N": 0.0}})
    mgl = rig.spec.boundary.link.m_g_l_Nm
    # ramp the motor torque slowly to hold the link at about 0.3 rad
    q_target = 0.3
    for k in range(4000):
        tau = mgl * math.sin(q_target) * min(1.0, k / 2000)
        rig.step(tau)
    # with friction the link settles within the friction band around the static angle
    tau_fc_bound = 0.052 * 2.0 * 0.04 * 2 * 150.0 * 1.5
    q_lo = math.asin(max(-1.0, (mgl * math.sin(q_target) - tau_fc_bound) / mgl))
    q_hi = math.asin(min(1.0, (mgl * math.sin(q_target) + tau_fc_bound) / mgl))
    assert q_lo - 0.02 <= rig.model.q_out_rad <= q_hi + 0.02
    assert abs(rig.model.dq_out_rad_s) < 0.05


def test_encoder_quantization():
    rig = SimulatedRig.from_mapping({**LINK_PLANT, "noise": {"encoder_counts_per_rev": 1000}})
    for _ in range(300):
        rig.step(1.0)
    q, dq, tau = rig.motor_feedback()
    step = 2 * math.pi / 1000
    assert abs(q / step - round(q / step)) < 1e-9
    assert abs(q - rig.model.q_in_rad) <= step / 2 + 1e-12
    assert tau == 1.0


def test_noise_free_preset_and_bad_config():
    assert SensorNoise.none().tension_N == 0.0
    with pytest.raises(ConfigError, match="plant.noise.tension_N"):
        SimulatedRig.from_mapping({**LINK_PLANT, "noise": {"tension_N": -1}})
    with pytest.raises(ConfigError, match="plant.output.mode"):
        SimulatedRig.from_mapping({**LINK_PLANT, "output": {"mode": "spring"}})
    with pytest.raises(ConfigError, match="plant.bogus"):
        SimulatedRig.from_mapping({**LINK_PLANT, "bogus": 1})
