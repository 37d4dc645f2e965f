"""The machinery of fits on long runs: the bounded Levenberg-Marquardt with threaded
finite-difference columns (models/common/projected_lm.py), the contiguous windows where
the fits start (models/closure/windows.py), and the simulation's restart at a gap.

Oracles: scipy's own finite-difference code (``approx_derivative``) and scipy's
``least_squares`` on the same problems; a windowed simulation against each window
simulated as a run of its own.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.optimize._numdiff import approx_derivative

from capstan.models.closure.dynamic.baseline import RESTART_GAP_S, _predict, fit_dynamic

from capstan.models.closure.dynamic.forms import DrivingForm
from capstan.models.closure.signals import signals_from_tables
from capstan.models.closure.windows import window_index
from capstan.models.common.errors import ModelError
from capstan.models.common.projected_lm import fd_jacobian, fd_steps, projected_lm
from capstan.tools.bench.closure import synthetic_run


def _problem():
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 4.0, 400)
    truth = np.array([2.0, 1.3, 0.4])
    y = truth[0] * np.exp(-truth[1] * t) + truth[2] + 0.01 * rng.standard_normal(t.size)
    return t, y, truth


def test_fd_columns_equal_scipy_two_point_with_relative_step_and_bounds() -> None:
    rng = np.random.default_rng(1)
    A = rng.standard_normal((60, 5))

    def f(x: np.ndarray) -> np.ndarray:
        return np.sin(A @ x) + x[0] ** 2

    # inside, at a lower bound (step flipped), at zero (fallback step), too close to both bounds
    x = np.array([0.5, -2.0, 0.0, 1e-3, 0.3])
    lo = np.array([0.0, -2.0, -1.0, -np.inf, 0.299])
    hi = np.array([0.502, 0.0, 1.0, np.inf, 0.3001])
    ref = approx_derivative(f, x, rel_step=1e-2, bounds=(lo, hi), method="2-point")
    for threads in (1, 2):
        J = fd_jacobian(f, x, f(x), lo, hi, 1e-2, n_threads=threads)
        assert np.array_equal(J, ref)
    # absolute steps where given, relative elsewhere
    h = fd_steps(x, lo, hi, 1e-2, np.array([np.nan, np.nan, 0.05, np.nan, np.nan]))
    assert h[2] == 0.05 and h[0] == -0.005


def test_lm_from_a_near_start_reaches_scipy_optimum() -> None:
    t, y, truth = _problem()

    def r(p: np.ndarray) -> np.ndarray:
        return p[0] * np.exp(-p[1] * t) + p[2] - y

    lo, hi = np.array([0.0, 0.0, -np.inf]), np.array([np.inf, np.inf, np.inf])
    ref = least_squares(r, truth * 1.5, bounds=(lo, hi), x_scale=truth, diff_step=1e-6)
    out = projected_lm(r, truth * 1.1, lo, hi, truth, 20, 1e-6, want_jac=True)
    assert np.allclose(out.x, ref.x, rtol=1e-4)
    assert out.cost == pytest.approx(ref.cost, rel=1e-6)
    assert out.jac is not None and out.jac.shape == (t.size, 3)
    # the Jacobian returned is the one at the final point
    assert out.jac_at_x and np.allclose(out.jac, approx_derivative(r, out.x, rel_step=1e-6), rtol=1e-3, atol=1e-6)


def test_lm_respects_bounds_and_never_raises_the_error() -> None:
    t, y, _ = _problem()

    def r(p: np.ndarray) -> np.ndarray:
        return p[0] * np.exp(-p[1] * t) + p[2] - y

    lo, hi = np.array([0.0, 0.0, -np.inf]), np.array([np.inf, 1.0, np.inf])     # rate capped below truth
    x0 = np.array([1.0, 0.5, 0.0])
    out = projected_lm(r, x0, lo, hi, np.ones(3), 30, 1e-6)
    assert out.x[1] == pytest.approx(1.0) and np.all(out.x >= lo) and np.all(out.x <= hi)
    assert out.cost <= 0.5 * float(np.sum(r(x0) ** 2))
    ref = least_squares(r, x0, bounds=(lo, hi), diff_step=1e-6)
    assert out.cost == pytest.approx(ref.cost, rel=1e-4)


def test_lm_refuses_a_non_finite_start() -> None:
    with pytest.raises(ModelError, match="not finite"):
        projected_lm(lambda p: np.array([np.nan, 1.0]), np.zeros(1), np.array([-1.0]), np.array([1.0]),
                     np.ones(1), 3, 1e-2)


def test_windows_are_contiguous_spread_and_start_each_run() -> None:
    sig = signals_from_tables([synthetic_run(2.0, seed=1), synthetic_run(1.0, seed=2)])
    n = len(sig)
    assert np.array_equal(window_index(sig, n), np.arange(n))            # short: everything
    idx = window_index(sig, 30_000, 5.0)
    assert 24_000 <= idx.size <= 30_000 and np.all(np.diff(idx) > 0)
    (a0, b0), (a1, b1) = sig.segments()
    assert a0 in idx and a1 in idx                                        # the first window at each start
    share0 = np.count_nonzero(idx < b0) / idx.size
    assert share0 == pytest.approx((b0 - a0) / n, abs=0.05)               # shares follow the run lengths
    pieces = np.split(idx, np.flatnonzero(np.diff(idx) != 1) + 1)
    assert len(pieces) >= 4 and all(p.size >= 4000 for p in pieces)       # ~5 s windows at 1 kHz
    assert idx[idx < b0].max() > 0.8 * b0                                 # spread to the run's end
    with pytest.raises(ValueError):
        window_index(sig, 0)


def test_simulation_restarts_at_a_gap_as_a_run_of_its_own() -> None:
    sig = signals_from_tables([synthetic_run(1.0, seed=4)])
    idx = window_index(sig, 20_000, 5.0)
    win = sig.take(idx)
    assert np.max(np.diff(win.t_s)) > RESTART_GAP_S
    p = np.array([20.0, 2.0, 1.7, 2e5, 1.1, 0.03, 0.02, 0.0])
    joined = _predict(DrivingForm.TESTBED, p, win, True)[0]
    pieces = np.split(np.arange(len(win)), np.flatnonzero(np.diff(idx) != 1) + 1)
    alone = np.concatenate([_predict(DrivingForm.TESTBED, p, win.take(k), True)[0] for k in pieces])
    assert np.array_equal(joined, alone)


@pytest.mark.slow
def test_long_run_fit_matches_the_fit_on_every_sample() -> None:
    """The windowed start + LM finish against scipy's fit on all samples of the same run."""
    sig = signals_from_tables([synthetic_run(2.0, seed=5)])
    ref = fit_dynamic(sig, warm_start_samples=len(sig))
    fast = fit_dynamic(sig, warm_start_samples=30_000)
    assert fast.rmse_Nm <= 1.02 * ref.rmse_Nm
    # truth of the synthetic plant: tau_fc 1.7 Nm, b_vis 0.02 Nm s/rad
    assert fast.params["tau_fc_Nm"] == pytest.approx(1.7, rel=0.02)
    assert fast.params["tau_fc_Nm"] == pytest.approx(ref.params["tau_fc_Nm"], rel=0.01)
    assert fast.stderr["tau_fc_Nm"] > 0.0 and fast.n_samples == len(sig)
    assert fast.pred_train_Nm is not None and fast.pred_train_Nm.shape == (len(sig),)
