"""The in-model ``drive_gain`` candidate (models/closure/dynamic/candidates.py): a gain error of
the input load cell, the simulation driven by ``(1 + eps)`` times the measured tau_in, scored by a
joint refit with the baseline against the same refit without it. Unit tests of the fitting code
on runs of the closure's own torsional unit; the evidence on another model family is the
``load_cell_gain`` case of tests/test_closure_families.py and tests/test_closure_long_runs.py.

* the candidate's drive is the measured drive scaled, nothing else; it is offered in the testbed
  form only and never when ``load`` is excluded;
* with the load cell reading 6 % high, the joint refit finds eps = 1 / 1.06 - 1 and reaches the
  noise floor, where the baseline refitted alone stays far above it (short path and the long
  path's windows);
* on clean runs eps stays at 0 and the refit gains nothing over the refit without it;
* a fit at the plausibility bound is reported implausible;
* (slow) on runs of the independent dense implementation of the distributed model
  (tests/independent_distributed.py: written from the paper alone, scipy Radau; N = 10, double
  bend, eq-23 field, 0.02 Nm noise, held out in another environment), ``capstan close`` selects
  the drive gain first on both paths with the injected +6 % gain error, and nothing on clean runs.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from capstan.models.closure import windows
from capstan.models.closure.dynamic.baseline import _predict
from capstan.models.closure.dynamic.candidates import GAIN_MAX, Refs, catalogue
from capstan.models.closure.dynamic.closure import _named, implausible, offers_gain, setup
from capstan.models.closure.dynamic.forms import DrivingForm
from capstan.models.closure.dynamic.in_model import InModelCloser, JointFit
from capstan.models.closure.dynamic.long_run import LongRunCloser
from capstan.models.closure.signals import signals_from_tables
from capstan.models.common.measurement_table import MeasurementTable
from capstan.models.closure.effects import Target
from capstan.models.closure.pipeline import close

from closure_plants import MU, R_M, double_bend, eq23_field, multisine
from test_closure_inmodel import unit_run
from tests.independent_distributed import IndepModel, Params

#: the module's runs are simulated once (about 25 s) and each closure takes several seconds
pytestmark = pytest.mark.slow

DT = 1e-3
NOISE_NM = 0.01
K_OUT = 20.0
GAIN = 1.06
EPS_TRUE = 1.0 / GAIN - 1.0
REFS = Refs(0.0, 1.0, 1.0, 1.0)


def _run(seed: int, gain: float, k_out: float) -> MeasurementTable:
    """A testbed run of the torsional unit whose input load cell reads ``gain`` x the drive torque."""
    return unit_run(seed, 0, 8.0, k_out, gain)


def _pair(gain: float):
    # held out in another environment: a gain error is not an environment's stiffness
    sig = signals_from_tables([_run(1, gain, K_OUT), _run(2, gain, 35.0)])
    return sig.take(sig.run_id == 0), sig.take(sig.run_id == 1)


@pytest.fixture(scope="module")
def gain_runs():
    return _pair(GAIN)


@pytest.fixture(scope="module")
def clean_runs():
    return _pair(1.0)


def _gain(train, excluded=None):
    effs = [e for e in catalogue(train, REFS, excluded or {}, [], gain=True) if e.name == "drive_gain"]
    assert len(effs) == 1
    return effs[0]


def _rmse(r: np.ndarray) -> float:
    return float(np.sqrt(np.mean(r * r)))


def test_the_candidate_scales_the_measured_drive_and_nothing_else(gain_runs) -> None:
    train, _ = gain_runs
    assert not any(e.name == "drive_gain" for e in catalogue(train, REFS, {}, []))        # offered on request
    assert not any(e.name == "drive_gain" for e in catalogue(train, REFS, {"load": "tied"}, [], gain=True))
    eff = _gain(train)
    assert eff.depends_on == ("load",) and eff.joint_scored and not eff.empirical
    assert (eff.lo, eff.hi) == ((-GAIN_MAX,), (GAIN_MAX,))
    m = eff.mods(train, {}, np.array([-0.05]))
    assert m.cap_scale is None and m.lag_s == 0.0 and m.c2_Nms2_rad2 == 0.0
    np.testing.assert_allclose(m.drive_Nm, -0.05 * train.ratio_q * train.tau_in_Nm, rtol=0, atol=1e-15)
    # the simulation with the gain is the simulation driven by the scaled channel
    ds = setup(*gain_runs)
    p = np.array(list(ds.fit.params.values()))
    with_gain = _predict(DrivingForm.TESTBED, p, train, True, m)[0]
    scaled = _predict(DrivingForm.TESTBED, p, replace(train, tau_in_Nm=0.95 * train.tau_in_Nm), True)[0]
    np.testing.assert_allclose(with_gain, scaled, rtol=0, atol=1e-9)


def test_it_is_offered_in_the_testbed_form_only(gain_runs) -> None:
    ds = setup(*gain_runs)
    assert ds.fit.spec.form == DrivingForm.TESTBED and offers_gain(ds)
    for form in (DrivingForm.ANGLES, DrivingForm.LINK, DrivingForm.OUTPUT_HELD):
        other = replace(ds, fit=replace(ds.fit, spec=replace(ds.fit.spec, form=form)))
        assert not offers_gain(other)


def test_a_load_cell_reading_6_percent_high_is_found_by_the_joint_refit(gain_runs) -> None:
    train, test = gain_runs
    ds = setup(train, test)
    closer = InModelCloser(ds.fit, train, test)
    current = JointFit(np.array(list(ds.fit.params.values())))
    jf, without, imp_train = closer.joint_pair(current, _gain(train))
    eps = float(jf.effects[-1][2][0])
    assert eps == pytest.approx(EPS_TRUE, abs=0.005)
    assert len(without) == 2 and imp_train >= 0.5
    after = _rmse(closer.predict(jf) - closer.yt)
    alone = min(_rmse(closer.predict(m) - closer.yt) for m in without)
    # the noise on tau_out is 0.01 Nm: the gain reaches it, the baseline refitted alone does not
    assert after <= 1.5 * NOISE_NM < 0.5 * alone, (after, alone)
    prm = _named(_gain(train), {}, np.array([eps]), 1.0, REFS)
    assert prm["load_cell_gain_error"] == pytest.approx(GAIN - 1.0, abs=0.006)
    assert implausible(_gain(train), np.array([eps])) == ""


def test_the_long_paths_windows_find_it_too(gain_runs, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(windows, "SCREEN_SAMPLES", 4_000)
    monkeypatch.setattr(windows, "SCREEN_WINDOW_S", 2.0)
    train, test = gain_runs
    ds = setup(train, test)
    closer = InModelCloser(ds.fit, train, test)
    lr = LongRunCloser(closer)
    assert len(lr.win.train) < len(train)                   # fitted on windows
    jf, without, imp = lr.joint_pair(JointFit(np.array(list(ds.fit.params.values()))), _gain(train))
    assert float(jf.effects[-1][2][0]) == pytest.approx(EPS_TRUE, abs=0.01)
    assert imp >= 0.3
    alone = min(_rmse(closer.predict(m) - closer.yt) for m in without)
    assert _rmse(closer.predict(jf) - closer.yt) < 0.5 * alone


def test_on_clean_runs_the_gain_stays_at_zero_and_gains_nothing(clean_runs) -> None:
    train, test = clean_runs
    ds = setup(train, test)
    closer = InModelCloser(ds.fit, train, test)
    jf, without, imp_train = closer.joint_pair(JointFit(np.array(list(ds.fit.params.values()))), _gain(train))
    assert abs(float(jf.effects[-1][2][0])) <= 0.005
    assert imp_train < 0.025                                # screened out (long_run.SCREEN_MIN)
    after = _rmse(closer.predict(jf) - closer.yt)
    alone = min(_rmse(closer.predict(m) - closer.yt) for m in without)
    assert after >= 0.95 * alone, (after, alone)          # not material (5 %)


def test_a_gain_at_its_plausibility_bound_is_implausible(gain_runs) -> None:
    eff = _gain(gain_runs[0])
    assert "plausibility bound" in implausible(eff, np.array([-GAIN_MAX]))
    assert "plausibility bound" in implausible(eff, np.array([GAIN_MAX]))
    assert implausible(eff, np.array([0.9 * GAIN_MAX])) == ""


def _independent_run(seed: int, k_out: float, b_out: float, gain: float, seconds: float = 15.0,
                     n_nodes: int = 10, T0_N: float = 150.0, noise_Nm: float = 0.02) -> MeasurementTable:
    """A testbed run of the independent dense model (the routing of tests/closure_plants.py),
    the input load cell reading ``gain`` times the drive torque; 0.2 s held at the first drive
    torque before the recording (the model starts from the eq-23 field, not at rest)."""
    th = double_bend(n_nodes)
    model = IndepModel(Params(th, th[::-1].copy(), eq23_field(th, T0_N, 0.9 * T0_N),
                              eq23_field(th[::-1], 0.95 * T0_N, T0_N), mu=MU, k_out=k_out, b_out=b_out))
    t = np.arange(-0.2, seconds, DT)
    u = multisine(np.maximum(t, 0.0), 6.0, seed)
    u[t < 0.0] = u[t >= 0.0][0]
    out = model.simulate(t, u, rtol=1e-6)
    keep = t >= -1e-12
    k = int(keep.sum())
    rng = np.random.default_rng(1000 + seed)
    q_out = out["q_out"][keep]
    cols = {"t": t[keep] - t[keep][0], "tau_in": gain * out["tau_in_cmd"][keep] + noise_Nm * rng.standard_normal(k),
            "tau_out": out["tau_out"][keep] + noise_Nm * rng.standard_normal(k), "q_in": out["q_in"][keep],
            "q_out": q_out, "dq_out": np.gradient(q_out, DT) + 1e-3 * rng.standard_normal(k)}
    return MeasurementTable(cols, {"r_in": R_M, "r_out": R_M, "environment": {"k_out": k_out, "b_out": b_out}},
                            f"independent{seed}")


#: measured shortfall (numpy 2.4.6 / scipy 1.17.1 / numba 0.68.1, 2026-11-28): on the long-run path the clean
#: independent runs select empirical:velocity (held-out 0.0260 Nm, -11.0 %); the short path selects nothing
LONG_CLEAN_SHORT = "long path, clean independent runs: empirical:velocity selected (0.0260 Nm, -11.0 %)"


def _long_path(monkeypatch: pytest.MonkeyPatch) -> None:
    """The long-run path's thresholds lowered as in tests/conftest.py (long_path)."""
    for name, value in (("WARM_START_SAMPLES", 5_000), ("WINDOW_SAMPLES", 10_000), ("WINDOW_S", 5.0),
                        ("SCREEN_SAMPLES", 10_000), ("SCREEN_WINDOW_S", 5.0)):
        monkeypatch.setattr(windows, name, value)


def _close_independent(gain: float):
    sig = signals_from_tables([_independent_run(1, 20.0, 2.0, gain), _independent_run(2, 35.0, 1.5, gain)])
    return close(sig.take(sig.run_id == 0), sig.take(sig.run_id == 1)).targets[Target.TAU_OUT]


@pytest.mark.slow
@pytest.mark.parametrize("path", ["short", "long"])
def test_on_the_independent_dense_model_the_gain_is_traced_and_measured(path: str,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    if path == "long":
        _long_path(monkeypatch)
    r = _close_independent(GAIN)
    assert r.selected and r.selected[0].effect == "drive_gain", [(c.effect, c.improvement) for c in r.selected]
    assert 1.0 - r.rmse_after_Nm / r.rmse_before_Nm >= 0.30, (r.rmse_before_Nm, r.rmse_after_Nm)
    assert r.selected[0].params["load_cell_gain_error"] == pytest.approx(GAIN - 1.0, abs=0.006)


@pytest.mark.slow
@pytest.mark.parametrize("path", ["short", pytest.param("long", marks=pytest.mark.xfail(strict=True,
                                                                                        reason=LONG_CLEAN_SHORT))])
def test_on_the_independent_dense_model_clean_runs_select_nothing(path: str,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    if path == "long":
        _long_path(monkeypatch)
    r = _close_independent(1.0)
    assert r.rmse_before_Nm <= 0.05 and r.selected == [], [(c.effect, c.improvement) for c in r.selected]
