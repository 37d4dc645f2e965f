"""The joint fit of the baseline's shape with extra columns (models.baseline_shape) and the
closure's channel realignment (models.closure_model), checked against independent
solutions: a dense least-squares solver, a friction law with known parameters, and a
delay whose size is known."""

from __future__ import annotations

import numpy as np
import pytest

from capstan.models.closure.baseline_shape import ShapeProblem, design, fit_shape
from capstan.models.closure.augmented import Realign, argmin_int, realigned_inputs, realigned_signals
from capstan.models.common.errors import ModelError
from capstan.models.closure.identification import ModelKind, friction_basis
from capstan.models.closure.signals import Signals


def _signals(n_runs: int = 2, n: int = 3000, dt_s: float = 1e-3, seed: int = 0) -> Signals:
    rng = np.random.default_rng(seed)
    t = np.concatenate([np.arange(n) * dt_s for _ in range(n_runs)])
    run = np.repeat(np.arange(n_runs), n)
    v = np.concatenate([0.8 * np.sin(2 * np.pi * (0.7 + 0.3 * k) * np.arange(n) * dt_s) for k in range(n_runs)])
    tin = 3.0 * np.sin(2 * np.pi * 0.4 * t) + rng.normal(0, 0.5, t.size)
    z = np.zeros_like(t)
    return Signals(t, run, tin, z.copy(), np.cumsum(v) * dt_s, v, np.gradient(v, dt_s), z.copy(), z.copy(), z.copy())


def test_blockwise_solution_equals_a_dense_least_squares_solve() -> None:
    rng = np.random.default_rng(3)
    n = 4000
    v = rng.uniform(-1.0, 1.0, n)
    tin = rng.normal(0, 2.0, n)
    extra = rng.normal(size=(n, 6))
    X = design(ModelKind.REDUCED, tin, v, 25.0, 0.07, extra)
    y = X @ np.array([0.9, 1.2, 0.4, 0.2, 0.05, 1.0, -2.0, 0.5, 0.0, 3.0, -1.0]) + rng.normal(size=n)
    theta, r = ShapeProblem(ModelKind.REDUCED, tin, v, y, extra).solve(25.0, 0.07)
    ref = np.linalg.lstsq(X, y, rcond=None)[0]
    assert ref[2] > 0.0          # the free optimum is inside the domain: the bound is not active
    assert np.allclose(theta, ref, rtol=1e-6, atol=1e-9)
    assert np.allclose(r, y - X @ ref, atol=1e-9)


def test_a_negative_stiction_excess_is_held_on_its_bound() -> None:
    """Friction that rises with speed cannot be rebuilt by an inverted Stribeck term: the
    constrained solution is the free least-squares solution without that column."""
    rng = np.random.default_rng(4)
    n = 4000
    v = rng.uniform(-1.0, 1.0, n)
    tin = rng.normal(0, 2.0, n)
    y = tin - np.tanh(30 * v) * (1.0 - 0.8 * np.exp(-(v / 0.3) ** 2)) + rng.normal(0, 0.01, n)
    X = design(ModelKind.REDUCED, tin, v, 30.0, 0.3)
    assert np.linalg.lstsq(X, y, rcond=None)[0][2] < 0.0
    theta, r = ShapeProblem(ModelKind.REDUCED, tin, v, y).solve(30.0, 0.3)
    keep = [0, 1, 3, 4]
    ref = np.linalg.lstsq(X[:, keep], y, rcond=None)[0]
    assert theta[2] == 0.0
    assert np.allclose(theta[keep], ref, rtol=1e-6, atol=1e-9)
    assert np.allclose(r, y - X[:, keep] @ ref, atol=1e-9)


def test_shape_refit_recovers_a_known_friction_law_from_a_wrong_start() -> None:
    rng = np.random.default_rng(5)
    n = 20000
    v = np.concatenate([rng.uniform(-1.2, 1.2, n // 2), rng.normal(0, 0.05, n // 2)])
    tin = rng.normal(0, 3.0, n)
    drag = v * np.abs(v)                                   # an extra column with a known coefficient
    true = np.array([1.0, 1.5, 0.45, 0.15, 0.0])            # ratio, tau_fc, excess, b_vis, offset
    y = friction_basis(ModelKind.REDUCED, v, tin, 30.0, 0.05) @ true - 2.0 * drag + rng.normal(0, 0.01, n)
    v95 = float(np.percentile(np.abs(v), 95))
    fit = fit_shape(ShapeProblem(ModelKind.REDUCED, tin, v, y, drag[:, None]), v95, start=(150.0, 0.4))
    assert fit.alpha_s_rad == pytest.approx(30.0, rel=0.05)
    assert fit.eta_s_rad_s == pytest.approx(0.05, rel=0.05)
    assert np.allclose(fit.theta[:5], true, atol=0.02)
    assert fit.theta[5] == pytest.approx(-2.0, rel=0.01)


def test_a_late_velocity_is_advanced_back_inside_each_run() -> None:
    sig = _signals()
    lag = 12
    late = sig.dq_out_rad_s.copy()
    for a, b in sig.segments():
        late[a + lag:b] = sig.dq_out_rad_s[a:b - lag]
        late[a:a + lag] = sig.dq_out_rad_s[a]
    delayed = Signals(sig.t_s, sig.run_id, sig.tau_in_Nm, sig.tau_out_Nm, sig.q_out_rad, late, sig.ddq_out_rad_s2,
                      sig.dwell_s, sig.rest_s, sig.slide_rad)
    r = Realign("dq_out", 0.012)
    tin, v = realigned_inputs(delayed, r)
    assert tin is delayed.tau_in_Nm
    for a, b in sig.segments():      # exact except the last lag samples of each run (held)
        assert np.array_equal(v[a:b - lag], sig.dq_out_rad_s[a:b - lag])
        assert np.all(v[b - lag:b] == late[b - 1])
    full = realigned_signals(delayed, r)
    assert np.array_equal(full.dq_out_rad_s, v)
    assert np.array_equal(full.q_out_rad, delayed.q_out_rad)           # not derived from the velocity


def test_a_late_output_torque_delays_every_input() -> None:
    sig = _signals()
    r = Realign("tau_out", 0.005)
    full = realigned_signals(sig, r)
    for a, b in sig.segments():
        assert np.array_equal(full.tau_in_Nm[a + 5:b], sig.tau_in_Nm[a:b - 5])
        assert np.array_equal(full.dq_out_rad_s[a + 5:b], sig.dq_out_rad_s[a:b - 5])
    assert np.array_equal(full.tau_out_Nm, sig.tau_out_Nm)


def test_realign_refuses_an_unknown_channel() -> None:
    with pytest.raises(ModelError):
        Realign("q_out", 0.01)


@pytest.mark.parametrize("lo, hi, m0", [(9, 17, 12), (71, 99, 85), (71, 99, 99), (13, 17, 13), (4, 4, 4)])
def test_integer_golden_section_finds_the_minimum(lo: int, hi: int, m0: int) -> None:
    calls: list[int] = []

    def f(m: int) -> float:
        calls.append(m)
        return (m - m0) ** 2 + 0.1 * m

    assert argmin_int(f, lo, hi) == m0
    assert len(calls) == len(set(calls)) and len(calls) <= 10
