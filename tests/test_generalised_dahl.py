"""The torsional unit's generalised Dahl law ``df/dx = k_pre sgn(u) |u|^i`` against physics:
an independent ODE integration (scipy), its limiting cases (i = 1: Dahl; i -> 0: the
elasto-plastic Jenkins element), the finite saturation travel for i < 1, a monotone approach
to the capacity and non-negative dissipation per closed loop; and the LINK form's damping of
the elastic path (Kelvin-Voigt) against its closed-form phase lead."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from capstan.models.closure.dynamic.baseline import DynamicFit

from capstan.models.closure.dynamic.forms import DrivingForm, choose_form, param_names
from capstan.models.closure.signals import signals_from_tables
from capstan.models.common.measurement_table import MeasurementTable
from capstan.models.transmission.stick_slip import dahl_u_update, friction_update, simulate_unit

K_PRE, F = 400.0, 1.5          # presliding stiffness [Nm/rad], capacity [Nm] (zeta_s = 1)


def _travel(f0: float, v: float, dt: float, n: int, i: float) -> np.ndarray:
    """Friction after each of ``n`` steps at constant velocity ``v`` (the unit's step law)."""
    out = np.empty(n)
    f = f0
    for k in range(n):
        f = friction_update(f, v, dt, K_PRE, F, 1.0, 0.05, i)
        out[k] = f
    return out


def _ode(f0: float, x_end: float, i: float, xs: np.ndarray) -> np.ndarray:
    """df/dx = k_pre |1 - f / F|^i sgn(1 - f / F) by scipy (positive motion), at travels xs."""
    def rhs(_x: float, f: np.ndarray) -> list[float]:
        u = 1.0 - f[0] / F
        return [K_PRE * math.copysign(abs(u) ** i, u)]
    sol = solve_ivp(rhs, (0.0, x_end), [f0], t_eval=xs, rtol=1e-10, atol=1e-12, method="LSODA")
    return sol.y[0]


@pytest.mark.parametrize("i", [0.3, 0.5, 1.5, 2.0, 3.5])
def test_the_step_is_the_exact_solution_of_the_law_at_constant_velocity(i: float) -> None:
    # from the opposite capacity (a full reversal, u0 = 2), 1 ms steps at 0.2 rad/s; the
    # exact update needs no small steps: it matches a tight ODE integration at every sample
    # (for i < 1 up to 0.9 of the saturation travel: the right-hand side is not Lipschitz at u = 0)
    dt, v = 1e-3, 0.2
    x_max = 0.9 * 2.0 ** (1.0 - i) * F / ((1.0 - i) * K_PRE) if i < 1.0 else 0.04
    n = int(x_max / (v * dt))
    f = _travel(-F, v, dt, n, i)
    xs = v * dt * np.arange(1, n + 1)
    ref = _ode(-F, xs[-1], i, xs)
    assert np.max(np.abs(f - ref)) < 1e-6 * F


def test_exponent_one_is_dahls_law_and_the_limit_of_the_exact_update() -> None:
    # the i = 1 step is the backward-Euler Dahl update the unit always had (bit for bit) ...
    f, v, dt = 0.3, 0.1, 1e-3
    assert friction_update(f, v, dt, K_PRE, F, 1.0, 0.05, 1.0) == \
        (f + K_PRE * dt * v) / (1.0 + K_PRE * dt * abs(v) / F)
    # ... and the exact update tends to Dahl's exponential u exp(-k x / F) as i -> 1
    a = K_PRE * v * dt / F
    for i in (1.0 - 1e-6, 1.0 + 1e-6):
        assert dahl_u_update(0.8, v * dt, K_PRE, F, i) == pytest.approx(0.8 * math.exp(-a), rel=1e-5)
    # backward Euler converges to the same exponential with small steps (first order)
    x_end = 0.01
    exact = F * (1.0 - 2.0 * math.exp(-K_PRE * x_end / F))
    errs = [abs(_travel(-F, v, dt, int(round(x_end / (v * dt))), 1.0)[-1] - exact) for dt in (1e-3, 5e-4)]
    assert errs[1] == pytest.approx(errs[0] / 2.0, rel=0.1)


@pytest.mark.parametrize("i", [0.25, 0.5, 0.8])
def test_below_one_the_capacity_is_reached_after_a_finite_travel(i: float) -> None:
    # x_sat = 2^(1-i) F / ((1-i) k_pre) after a full reversal: below it f < F, beyond it f = F
    x_sat = 2.0 ** (1.0 - i) * F / ((1.0 - i) * K_PRE)
    v, dt = 0.05, 1e-4
    n = int(round(1.5 * x_sat / (v * dt)))
    f = _travel(-F, v, dt, n, i)
    x = v * dt * np.arange(1, n + 1)
    assert np.all(f[x < 0.98 * x_sat] < F) and F - f[x < 0.5 * x_sat][-1] > 1e-3
    assert np.all(f[x > x_sat * (1 + 1e-9)] == F)
    # i = 1/2 (uniformly spread slip thresholds, an Iwan element): a parabola in the travel
    if i == 0.5:
        xx = x[x < x_sat]
        parab = -F + K_PRE * math.sqrt(2.0) * xx - (K_PRE * xx) ** 2 / (4.0 * F)
        assert np.max(np.abs(f[x < x_sat] - parab)) < 1e-9


def test_exponent_towards_zero_is_the_elasto_plastic_jenkins_element() -> None:
    # i -> 0: stiffness k_pre all the way to the capacity, then the Coulomb level
    v, dt = 0.05, 1e-4
    x_el = 2.0 * F / K_PRE                       # the elastic travel from -F to +F
    n = int(round(2.0 * x_el / (v * dt)))
    x = v * dt * np.arange(1, n + 1)
    jenkins = np.minimum(-F + K_PRE * x, F)
    for i, tol in ((0.05, 0.06), (0.01, 0.015)):
        f = _travel(-F, v, dt, n, i)
        assert np.max(np.abs(f - jenkins)) < tol * 2.0 * F


@pytest.mark.parametrize("i", [0.2, 0.5, 1.0, 2.0, 3.5])
def test_monotone_approach_and_non_negative_dissipation_per_closed_loop(i: float) -> None:
    # displacement-driven cycles x = A sin(w t): f moves with the motion and never beyond F;
    # the loop's work  W = oint f dx  is the energy dissipated, > 0 for every exponent
    dt, w = 1e-4, 2 * math.pi * 2.0
    t = np.arange(0.0, 2.0, dt)
    for A in (0.2 * F / K_PRE, 3.0 * F / K_PRE):
        x = A * np.sin(w * t)
        v = np.diff(x) / dt
        f = np.empty(v.size)
        fk = 0.0
        for k in range(v.size):
            fk = friction_update(fk, v[k], dt, K_PRE, F, 1.0, 0.05, i)
            f[k] = fk
        df = np.diff(f)
        assert np.all(df * v[1:] >= -1e-12)               # never against the motion
        assert np.max(np.abs(f)) <= F * (1 + 1e-12)
        last = t[1:] >= 1.5                                 # the last (steady) cycle of four
        W = float(np.sum(f[last] * v[last]) * dt)
        # dissipated, and at most the rigid-plastic loop 4 F A (|f| <= F)
        assert 0.0 < W <= 4.0 * F * A
        if i == 0.2 and A > 2.0 * F / K_PRE:
            # near the Jenkins element: its parallelogram 2 F (2 A - 2 F / k_pre) within 10 %
            assert W == pytest.approx(2.0 * F * (2.0 * A - 2.0 * F / K_PRE), rel=0.1)


def _link_signals(t: np.ndarray, q_in: np.ndarray, tau_out: np.ndarray):
    cols = {"t": t, "tau_in": np.zeros_like(t), "tau_out": tau_out, "q_in": q_in, "q_out": q_in.copy()}
    return signals_from_tables([MeasurementTable(cols, {"output": "link", "r_in": 0.04, "r_out": 0.04}, "link")])


def test_damping_of_the_elastic_path_leads_by_its_closed_form_phase() -> None:
    # a stuck sheath (capacity never reached): tau_in = K (q_in - x0) + d_in dq_in, the
    # Kelvin-Voigt response, whose phase lead over q_in is atan(w d_in / K)
    t = np.arange(0.0, 4.0, 1e-3)
    fq = 2.0
    q_in = 2e-3 * np.sin(2 * np.pi * fq * t)
    sig = _link_signals(t, q_in, np.full_like(t, 0.0) + 0.3 * np.sin(2 * np.pi * 0.7 * t))
    spec = choose_form(sig)
    assert spec.form == DrivingForm.LINK
    K, d = 600.0, 10.0
    p = {"K_in_Nm_rad": K, "g_out": 1.0, "tau_fc_Nm": 500.0, "k_pre_Nm_rad": 1e9, "zeta_s": 1.0,
         "eta_s_rad_s": 0.05, "b_vis_Nms_rad": 0.0, "offset_in_Nm": 0.0, "dahl_exp": 1.0, "d_in_Nms_rad": d}
    assert set(p) == set(param_names(DrivingForm.LINK))
    pred = DynamicFit(spec, p).predict(sig)
    mid = (t > 0.5) & (t < 3.5)
    wq = 2 * np.pi * fq
    basis = np.column_stack([np.sin(wq * t[mid]), np.cos(wq * t[mid]), np.ones(int(mid.sum()))])
    s, c, _ = np.linalg.lstsq(basis, pred[mid], rcond=None)[0]
    assert math.atan2(c, s) == pytest.approx(math.atan(wq * d / K), abs=0.01)
    assert math.hypot(s, c) == pytest.approx(2e-3 * math.hypot(K, wq * d), rel=0.01)
    # without the damping: in phase (the unit as before)
    pred0 = DynamicFit(spec, {**p, "d_in_Nms_rad": 0.0}).predict(sig)
    s0, c0, _ = np.linalg.lstsq(basis, pred0[mid], rcond=None)[0]
    assert abs(math.atan2(c0, s0)) < 1e-3


def test_unit_default_exponent_is_bit_identical_to_dahl() -> None:
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 3.0, 1e-3)
    a = np.cumsum(rng.normal(0.0, 0.05, t.size))
    outs = []
    for extra in ((), (1.0,)):
        x, v, f = np.empty(t.size), np.empty(t.size), np.empty(t.size)
        simulate_unit(t, a, np.array([0, t.size]), np.array([0.0]), np.array([0.02]), np.array([50.0]), 3000.0, 0.8,
                      1.2, 0.05, 0.01, x, v, f, np.empty(0), 0.0, *extra)
        outs.append(x.copy())
    assert np.array_equal(outs[0], outs[1])
