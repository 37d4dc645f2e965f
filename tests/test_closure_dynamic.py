"""The closure's dynamic baseline: the friction-state unit against physics (limiting cases,
an independent linear simulation), the fit on runs of the distributed model (another
model family, N = 12, double-bend curvature, eq-23 field) against the paper's eq 19, and
on the da Vinci files of tests/data (real data)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy import signal as sps

from capstan.models.closure.dynamic.baseline import fit_dynamic

from capstan.models.closure.dynamic.forms import DrivingForm, choose_form
from capstan.models.closure.signals import signals_from_tables
from capstan.models.common.errors import ModelError
from capstan.models.common.measurement_table import MeasurementTable
from capstan.models.transmission.stick_slip import simulate_unit

from closure_plants import MU, R_M, distributed_run, double_bend, eq23_field

REPO = Path(__file__).resolve().parent.parent
DATA = REPO / "tests" / "data" / "davinci-cable-tool"
DESC = REPO / "config" / "imports" / "davinci.yaml"


def _unit(t, a, kx, c0, kp, tfc, zs=1.0, eta=0.05, bv=0.0, x0=0.0):
    n = len(t)
    x, v, f = np.empty(n), np.empty(n), np.empty(n)
    done = simulate_unit(t, a, np.array([0, n]), np.array([x0]), np.array([c0]), np.array([kx]), kp, tfc, zs, eta,
                         bv, x, v, f, np.empty(0))
    assert done == n
    return x, v, f


def test_without_friction_the_testbed_unit_is_the_first_order_environment() -> None:
    # b q' + k q = tau_in: compared with scipy's continuous-time simulation; backward
    # Euler is first order: the error is within dt * max|q'| and halves with dt
    errs = []
    for dt in (1e-3, 5e-4):
        t = np.arange(0.0, 5.0, dt)
        u = 2.0 * np.sin(2 * np.pi * 0.7 * t) + np.sin(2 * np.pi * 3.1 * t)
        x, _, f = _unit(t, u, kx=20.0, c0=2.0, kp=1e5, tfc=0.0)
        _, y, _ = sps.lsim(sps.lti([1.0], [2.0, 20.0]), u, t)
        assert np.max(np.abs(f)) == 0.0
        errs.append(float(np.max(np.abs(x - y))))
        assert errs[-1] < dt * float(np.max(np.abs(np.gradient(y, dt))))
    assert errs[1] == pytest.approx(errs[0] / 2.0, rel=0.1)


def test_stick_holds_the_state_until_the_capacity_then_slides_at_the_coulomb_level() -> None:
    t = np.arange(0.0, 4.0, 1e-3)
    a = 0.5 * t                          # slowly rising demand, capacity zeta_s tau_fc = 1.3 Nm
    x, v, f = _unit(t, a, kx=1e-9, c0=0.05, kp=1e6, tfc=1.0, zs=1.3, eta=0.02)
    stuck = a < 1.29
    # held within the presliding travel of the Dahl element, x = -(F / k_pre) ln(1 - f / F)
    # with F = zeta_s tau_fc at rest: microradians up to the capacity, not a creep
    dahl = -(1.3 / 1e6) * np.log(1.0 - a[stuck] / 1.3)
    assert np.allclose(x[stuck], dahl, rtol=0.02, atol=2e-8) and np.max(x[stuck]) < 1e-5
    assert np.allclose(f[stuck][10:], a[stuck][10:], atol=2e-3)  # friction takes what the balance demands
    assert np.all(v[a > 1.35] > 0.0)                             # breakaway past the capacity
    # sliding well above eta_s: the friction is the Coulomb level (zeta_c tau_fc = 1)
    fast = v > 0.2
    assert fast.any() and np.allclose(f[fast], 1.0, atol=1e-3)
    # and the balance c0 v + f = a holds there
    assert np.allclose(0.05 * v[fast] + f[fast], a[fast], atol=2e-3)


def test_reversal_keeps_the_elastic_state_within_the_band() -> None:
    # a demand oscillating inside the capacity never moves the state (no tanh creep)
    t = np.arange(0.0, 10.0, 1e-3)
    a = 0.9 * np.sin(2 * np.pi * 0.5 * t)
    x, v, _ = _unit(t, a, kx=1e-9, c0=0.01, kp=1e7, tfc=1.0, zs=1.0)
    assert np.max(np.abs(x)) < 1e-6


def _dist_signals(k_test: float = 35.0, b_test: float = 1.5, seconds: float = 15.0):
    tr, _ = distributed_run(seconds, seed=1, k_out=20.0, b_out=2.0, source="train")
    te, truth = distributed_run(seconds, seed=2, k_out=k_test, b_out=b_test, source="test")
    sig = signals_from_tables([tr, te])
    return sig.take(sig.run_id == 0), sig.take(sig.run_id == 1), truth


@pytest.fixture(scope="module")
def dist_clean():
    return _dist_signals()


@pytest.mark.slow
def test_distributed_clean_runs_reach_the_noise_floor_in_another_environment(dist_clean) -> None:
    train, test, truth = dist_clean
    spec = choose_form(train)
    assert spec.form == DrivingForm.TESTBED and spec.target == "tau_out"
    fit = fit_dynamic(train)
    pred = fit.predict(test)
    rmse = float(np.sqrt(np.mean((pred - test.tau_out_Nm) ** 2)))
    assert rmse <= 0.05                                     # issue bar, at 0.02 Nm sensor noise
    assert float(np.sqrt(np.mean((pred - truth["tau_out"]) ** 2))) < 0.04
    assert not fit.implausible and "tau_fc_Nm" not in fit.at_bound
    # the capacity is the paper's eq 19 on the eq-25 averaged pretension of this routing:
    # tau_fc = (mu theta / 2)(T0_eq,upper + T0_eq,lower) r with T0_eq = 2 T(s_min) per cable
    th = double_bend(12)
    t_up = eq23_field(th, 150.0, 135.0).min()
    t_lo = eq23_field(th[::-1], 142.5, 150.0).min()
    tau_fc_eq19 = MU * 3.0 * (t_up + t_lo) * R_M
    assert fit.params["tau_fc_Nm"] == pytest.approx(tau_fc_eq19, rel=0.05)
    assert fit.stderr["tau_fc_Nm"] < 0.05 * fit.params["tau_fc_Nm"]


def test_driving_form_follows_the_channels_present() -> None:
    t = np.arange(0.0, 2.0, 1e-3)
    q = 0.3 * np.sin(2 * np.pi * t)
    base = {"t": t, "tau_in": np.sin(2 * np.pi * t), "q_out": q}
    held = MeasurementTable({**base, "tau_out": 0.2 + 1e-4 * np.cos(t), "q_in": q}, {}, "held")
    assert choose_form(signals_from_tables([held])).form == DrivingForm.OUTPUT_HELD
    env = MeasurementTable({**base, "tau_out": 0.5 * q}, {"environment": {"k_out": 20.0, "b_out": 2.0}}, "env")
    assert choose_form(signals_from_tables([env])).form == DrivingForm.TESTBED
    ang = MeasurementTable({**base, "tau_out": 0.5 * q, "q_in": q}, {}, "ang")
    assert choose_form(signals_from_tables([ang])).form == DrivingForm.ANGLES
    no_qin = MeasurementTable({**base, "tau_out": 0.2 + 0 * t}, {}, "no_qin")
    with pytest.raises(ModelError, match="q_in"):
        choose_form(signals_from_tables([no_qin]))


@pytest.mark.slow
def test_davinci_held_out_skill_on_tau_in_with_plausible_parameters() -> None:
    from capstan.tools.offline.run_inputs import load_runs
    names = ["00", "12", "23", "33", "43"]
    tabs = load_runs([str(DATA / f"Tool_4_Maryland_L2_{n}.TXT") for n in names], str(DESC))
    sig = signals_from_tables(tabs)
    train, test = sig.take(sig.run_id < 3), sig.take(sig.run_id >= 3)
    fit = fit_dynamic(train)
    assert fit.spec.form == DrivingForm.OUTPUT_HELD and fit.spec.target == "tau_in"
    assert not fit.warnings                     # the import's signs give positive input power
    pred = fit.predict(test)
    for a, b in test.segments():
        y = test.tau_in_Nm[a:b]
        skill = 1.0 - math.sqrt(float(np.mean((pred[a:b] - y) ** 2))) / float(np.std(y))
        assert skill >= 0.5
    # friction, ratio and stiffnesses inside the physical domain and plausible; zeta_s may
    # sit on zeta_c (no stiction peak: a result, reported as at its bound, eta_s then moot)
    assert not fit.implausible and set(fit.at_bound) <= {"zeta_s", "b_vis_Nms_rad"}
    assert fit.params["tau_fc_Nm"] > 0.0 and fit.params["g_out"] > 0.0
    if "zeta_s" in fit.at_bound:
        assert "eta_s_rad_s" in fit.undetermined


def test_a_range_violation_within_its_uncertainty_is_reported_as_weak_not_implausible() -> None:
    """A value outside its plausible range is implausible only if it stays outside when moved by
    1.96 standard errors either way; otherwise it is reported as weakly determined (a warning),
    never silently accepted (the lock-step LINK run's zeta_s 3.49 +- 1.74 at eta_s 5 mrad/s)."""
    from capstan.models.transmission.unit_plausibility import plausibility, split_by_uncertainty
    params = {"zeta_s": 3.49, "eta_s_rad_s": 0.005, "tau_fc_Nm": 1.8, "K_in_Nm_rad": 700.0}
    y = np.linspace(-3.0, 3.0, 101)
    imp = plausibility(params, y, 0.5)
    assert set(imp) == {"zeta_s"}
    est, weak = split_by_uncertainty(imp, params, {"zeta_s": 1.74}, y, 0.5)
    assert not est and len(weak) == 1 and weak[0].startswith("zeta_s") and "weakly determined" in weak[0]
    est, weak = split_by_uncertainty(imp, params, {"zeta_s": 0.1}, y, 0.5)      # 3.49 - 0.2 > 3
    assert set(est) == {"zeta_s"} and not weak
    est, weak = split_by_uncertainty(imp, params, {}, y, 0.5)                    # no standard error
    assert set(est) == {"zeta_s"} and not weak
    # a lower-bound range (the elastic path's time constant) is moved the other way
    p2 = {"d_in_Nms_rad": 80.0, "K_in_Nm_rad": 700.0}
    imp2 = plausibility(p2, y, 0.5)
    assert set(imp2) == {"d_in_Nms_rad"}
    assert not split_by_uncertainty(imp2, p2, {"d_in_Nms_rad": 10.0}, y, 0.5)[0]     # 80 - 19.6 < 70
    assert set(split_by_uncertainty(imp2, p2, {"d_in_Nms_rad": 2.0}, y, 0.5)[0]) == {"d_in_Nms_rad"}
