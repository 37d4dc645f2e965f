"""Pieces of the in-model closure (models/closure/dynamic/candidates.py, in_model.py, closure.py) on
runs of the closure's own torsional unit (the fitting code's unit tests; the evidence that
the closure works on other model families is tests/test_closure_families.py):

* a late target sensor is found at its whole-sample lag, also between the lag grid's points,
  and the baseline refitted on the realigned channels comes back to the noise floor;
* the realignment moves only the channels the baseline predicts;
* the drive-gain curve over the input pulley's angle carries no constant gain (a constant
  gain error is not an angle's effect).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from capstan.models.closure.dynamic.baseline import DynamicFit

from capstan.models.closure.dynamic.forms import DrivingForm, FormSpec
from capstan.models.closure.dynamic.closure import _refit_realigned, realigned, setup
from capstan.models.closure.dynamic.in_model import InModelCloser, JointFit
from capstan.models.closure.dynamic.candidates import Refs, catalogue
from capstan.models.closure.signals import signals_from_tables
from capstan.models.common.measurement_table import MeasurementTable
from capstan.models.transmission.stick_slip import simulate_unit

DT = 1e-3
NOISE_NM = 0.01
K_OUT, B_OUT = 20.0, 2.0
TAU_FC, K_PRE, B_VIS = 1.2, 2.0e5, 0.01


def unit_run(seed: int, lag_samples: int = 0, seconds: float = 8.0, k_out: float = K_OUT,
             gain: float = 1.0) -> MeasurementTable:
    """A testbed run of the torsional unit (the drive torque u drives k_out, b_out through the sheath
    friction), tau_out measured ``lag_samples`` late, the input load cell reading ``gain * u``; the rig
    rests before the recording."""
    t = np.arange(0.0, seconds, DT)
    rng = np.random.default_rng(seed)
    u = sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) for f in (0.3, 0.7, 1.3))
    u = 4.0 * u / np.max(np.abs(u))
    n = len(t)
    x, v, f = np.empty(n), np.empty(n), np.empty(n)
    assert simulate_unit(t, u, np.array([0, n]), np.array([0.0]), np.array([B_OUT]), np.array([k_out]), K_PRE,
                         TAU_FC, 1.0, 0.05, B_VIS, x, v, f, np.empty(0)) == n
    tau_out = k_out * x + B_OUT * v
    late = np.concatenate([np.full(lag_samples, tau_out[0]), tau_out[:n - lag_samples]]) if lag_samples else tau_out
    cols = {"t": t, "tau_in": gain * u + NOISE_NM * rng.standard_normal(n),
            "tau_out": late + NOISE_NM * rng.standard_normal(n),
            "q_out": x, "dq_out": v + 1e-4 * rng.standard_normal(n), "q_in": x + 1e-3 * np.sin(3.0 * t)}
    return MeasurementTable(cols, {"environment": {"k_out": k_out, "b_out": B_OUT}, "r_in": 1.0, "r_out": 1.0},
                            f"unit{seed}")


@pytest.fixture(scope="module")
def late_runs():
    sig = signals_from_tables([unit_run(1, 20), unit_run(2, 20)])
    return sig.take(sig.run_id == 0), sig.take(sig.run_id == 1)


@pytest.mark.slow
def test_a_late_sensor_is_found_at_its_lag_between_the_grid_points_and_the_refit_reaches_the_noise_floor(
        late_runs) -> None:
    train, test = late_runs
    ds = setup(train, test)
    closer = InModelCloser(ds.fit, train, test)
    eff = next(e for e in catalogue(train, Refs(0.0, 1.0, 1.0, 1.0), ds.excluded, []) if e.name == "sensor_latency")
    assert not any(abs(sh["lag_s"] - 0.020) < 1e-9 for sh in eff.grid)      # 20 ms is not a grid point
    current = JointFit(np.array(list(ds.fit.params.values())))
    shape = closer.best_shape(current, eff)
    joint = closer.refit(current, eff, shape, base_free=True)
    final = _refit_realigned(closer, joint, eff, shape)
    lag = final.effects[-1][1]["lag_s"]
    assert lag == pytest.approx(0.020, abs=0.5 * DT)
    rmse = float(np.sqrt(np.mean((closer.predict(final) - closer.yt) ** 2)))
    before = float(np.sqrt(np.mean((ds.pred_test_Nm - ds.y_test_Nm) ** 2)))
    # the noise on tau_out is 0.01 Nm: the realigned model is at it, the misaligned far above
    assert rmse <= 1.3 * NOISE_NM < 0.5 * before, (rmse, before)


def test_realignment_moves_only_the_predicted_channels(late_runs) -> None:
    train, _ = late_runs
    testbed = DynamicFit(FormSpec(DrivingForm.TESTBED, "tau_out", ("tau_in", "environment"), ""), {})
    angles = replace(testbed, spec=FormSpec(DrivingForm.ANGLES, "tau_out", ("q_in", "q_out"), ""))
    r = realigned(train, testbed, 0.005)
    assert np.array_equal(r.tau_in_Nm, train.tau_in_Nm)
    np.testing.assert_array_equal(r.tau_out_Nm[:-5], train.tau_out_Nm[5:])      # advanced by 5 samples
    assert np.all(r.tau_out_Nm[-5:] == train.tau_out_Nm[-1])                     # the end held
    ra = realigned(train, angles, 0.005)
    np.testing.assert_array_equal(ra.tau_in_Nm[:-5], train.tau_in_Nm[5:])       # both torques predicted


def test_the_drive_gain_over_the_pulley_angle_carries_no_constant_gain(late_runs) -> None:
    train, _ = late_runs
    eff = next(e for e in catalogue(train, Refs(0.0, 1.0, 1.0, 1.0), {}, [], drive_gain=("q_in",))
               if e.name == "empirical:q_in")
    assert eff.drive_gain and eff.depends_on == ("q_in",)
    k = len(eff.coef_names)
    const = eff.mods(train, {}, np.full(k, 0.05)).drive_Nm
    assert const is not None and np.max(np.abs(const)) < 1e-12
    ramp = eff.mods(train, {}, np.linspace(-0.05, 0.05, k)).drive_Nm
    assert ramp is not None and np.max(np.abs(ramp)) > 1e-3
    # a gain: zero where the drive torque is zero, proportional to it elsewhere
    g = ramp / np.where(np.abs(train.tau_in_Nm) > 0.5, train.tau_in_Nm, np.nan)
    assert np.nanmax(np.abs(g)) <= 0.1 + 1e-12      # within the span of the coefficients


def test_the_direction_curve_scales_the_capacity_by_the_sign_of_the_motion(late_runs) -> None:
    train, _ = late_runs
    assert not any(e.name == "empirical:direction" for e in catalogue(train, Refs(0.0, 1.0, 1.0, 1.0), {}, []))
    eff = next(e for e in catalogue(train, Refs(0.0, 1.0, 1.0, 1.0), {}, ["velocity"])
               if e.name == "empirical:direction")
    assert eff.depends_on == ("velocity",) and eff.empirical
    cap = eff.mods(train, {}, np.array([0.3])).cap_scale
    assert cap is not None
    fast = np.abs(train.dq_out_rad_s) > 10.0 * train.v_rest_rad_s
    assert np.any(fast & (train.dq_out_rad_s > 0)) and np.any(fast & (train.dq_out_rad_s < 0))
    np.testing.assert_allclose(cap[fast & (train.dq_out_rad_s > 0)], 1.3, atol=1e-3)
    np.testing.assert_allclose(cap[fast & (train.dq_out_rad_s < 0)], 0.7, atol=1e-3)
    d = InModelCloser.describe(eff, np.array([0.3]), 2.0, 1.0)
    assert d is not None and "x 1.3 for dq_out > 0" in d["text"] and d["peak_to_peak_Nm"] == pytest.approx(1.2)
