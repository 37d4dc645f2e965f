"""The closure's path for long runs -- the baseline fitted on contiguous windows and finished
on every sample, candidates screened on windows and scored on every held-out sample, the
winner refitted with the baseline on every sample (models/closure/windows.py,
models/closure/dynamic/long_run.py, models/common/projected_lm.py) -- on runs of another model family:
the distributed-model testbed runs of tests/test_closure_families.py (N = 12, double bend,
eq-23 field, noise 0.02 Nm, held-out runs in another environment), with the long-run
thresholds lowered so that these 15 s runs take that path. The bars are the short path's.
"""

from __future__ import annotations

import pytest

from capstan.models.closure import windows
from capstan.models.closure.effects import Target
from capstan.models.closure.pipeline import ClosureResult

from test_closure_families import SIGNAL, close_runs

pytestmark = pytest.mark.slow


def _close(effect: str) -> ClosureResult:
    # not the cached run() of test_closure_families: its results may come from the short path
    return close_runs(effect)


def test_clean_runs_on_the_long_path(long_path: None) -> None:
    res = _close("none")
    r = res.targets[Target.TAU_OUT]
    assert res.dynamic is not None
    fit = res.dynamic.fit
    n_train = len(res.dynamic.y_train_Nm)
    assert n_train > windows.WARM_START_SAMPLES               # the long path was taken
    assert fit.n_samples == n_train                             # the reported fit is on every sample
    assert r.rmse_before_Nm <= 0.05
    # eq 19 on the routing's eq-23/25 pretension: 1.73 Nm (test_closure_dynamic)
    assert fit.params["tau_fc_Nm"] == pytest.approx(1.73, rel=0.05)
    assert r.selected == [], [(c.effect, c.improvement, c.ci_low) for c in r.selected]
    # every candidate says on how many held-out samples it was scored
    n_test = len(res.dynamic.y_test_Nm)
    assert all(c.held_out_samples == n_test or (c.screened_out and not c.significant) for c in r.candidates)


#: measured shortfalls of the long path at this scale (the short path meets them)
SHORT_LONG = {
    "load_cell_gain": "measured 2026-11-26 (plant settled before recording): held-out 0.095 -> 0.032 Nm (-66 %) "
                      "but empirical:position is selected first, not load (short path: empirical:load)",
}


@pytest.mark.parametrize("effect", [pytest.param(e, marks=pytest.mark.xfail(strict=True, reason=SHORT_LONG[e]))
                                    if e in SHORT_LONG else e
                                    for e in ["bending_with_angle", "pretension_creep", "load_cell_gain"]])
def test_injected_effects_on_the_long_path(long_path: None, effect: str) -> None:
    res = _close(effect)
    r = res.targets[Target.TAU_OUT]
    assert r.selected, f"{effect}: nothing selected (baseline {r.rmse_before_Nm:.4f} Nm)"
    assert set(r.selected[0].depends_on) & SIGNAL[effect], [(c.effect, c.depends_on) for c in r.selected]
    assert 1.0 - r.rmse_after_Nm / r.rmse_before_Nm >= 0.30, (r.rmse_before_Nm, r.rmse_after_Nm)
    # the selected ones were scored on every held-out sample
    assert res.dynamic is not None
    assert all(c.held_out_samples == len(res.dynamic.y_test_Nm) for c in r.selected)
