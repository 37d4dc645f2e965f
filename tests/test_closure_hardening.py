"""Evidence from another model family: a strain-hardening cable in the distributed model
(N = 12, double-bend non-uniform curvature, eq-23 pretension field, noise 0.02 Nm; the
families harness of tests/closure_plants.py), its cable law ``f = k_c D (1 + c D^2)`` with the
slack lengths set so the pretension field is the clean run's -- only the stiffness changes.
Training and held-out runs in different environments (k_out 20 / 35 Nm/rad) and excitations.

What a pretensioned pull-pull pair makes of a hardening cable
(:mod:`capstan.models.transmission.hardening`): the pair's torque is
``2 r^2 k_c (1 + 3 c D0^2) theta + 2 r^4 k_c c theta^3`` -- mostly a *stiffer linear* cable; the
cubic is at most ``0.148 (d / D0)^2`` of the tangent stiffness. So:

* the testbed form (tau_in drives the declared environment; the cable's stiffness is not in
  the predicted channel): at c = 3e5 1/m^2 (T0 150 N, each cable's tangent stiffness +41 % from
  the pretension to the run's peak tension) the effect is immaterial -- baseline at the clean
  floor, nothing selected;
* the two-angle form (both angles drive, tau_out is the cable's elastic torque): a low
  pretension (T0 80 N, peak drive 8 Nm: a cable's tension swings 80 +- 55 N, its tangent
  stiffness rises ~+90 % from the pretension to the peak, the pair's ~+10 %) with c = 3e5.
  The fitted baseline stiffness is the pair's linearised one (K_c ~400 against
  240 (1 + 3 c D0^2) = 405 Nm/rad). The in-model ``strain_stiffening`` (the cubic of the cable
  paths and the friction the cables' rising mean tension adds) must be selected first, cut the
  held-out RMSE by >= 30 %, and land near the values the cable maps to: ``c_node = 4 c r^2 /
  (1 + 3 c D0^2)`` (within 25 %: the eq-23 field's D0 varies along the sheath) and ``beta`` in
  its physical range ``[3, 9]``;
  on five excitation seed pairs (1 / 2 ... 9 / 10, all kept), on >= 4 of 5;
* the same two cases on the long-run path (windows; the simulation restarted inside a window
  from the node the measured tau_out sets, the friction holding it);
* clean two-angle runs of the same pretension on the same five seed pairs: baseline <= 0.05 Nm
  and nothing selected on >= 4 of 5. (On seeds 3 / 4 the clean two-angle baseline has been
  0.052 Nm with pretension_relaxation selected: a time-like residual of the two-angle form on
  15 s runs, not this effect; a seed is a draw, so it stays in and the bar is a rate.)
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest

from capstan.models.closure.effects import Target
from capstan.models.closure.pipeline import ClosureResult, close
from capstan.models.closure.signals import signals_from_tables

from closure_plants import distributed_run

pytestmark = pytest.mark.slow

SECONDS = 15.0

#: case -> (form: "testbed" / "angles", cable's cubic c [1/m^2], pretension T0 [N], peak drive [Nm],
#: excitation seeds of the training and held-out runs)
CASES = {
    "angles_clean": ("angles", 0.0, 80.0, 6.0, (1, 2)),
    "angles_hardening": ("angles", 3e5, 80.0, 8.0, (1, 2)),
    "testbed_hardening": ("testbed", 3e5, 150.0, 6.0, (1, 2)),
}
#: the excitation seed pairs of the rate tests (training, held-out), all kept, and how many must pass
PAIRS = ((1, 2), (3, 4), (5, 6), (7, 8), (9, 10))
RATE = 4
for _k, _pair in enumerate(PAIRS[1:], start=2):
    CASES[f"angles_clean_{_k}"] = CASES["angles_clean"][:4] + (_pair,)
    CASES[f"angles_hardening_{_k}"] = CASES["angles_hardening"][:4] + (_pair,)


def _seeded(case: str) -> list[str]:
    """The case on every seed pair of :data:`PAIRS`."""
    return [case] + [f"{case}_{k}" for k in range(2, len(PAIRS) + 1)]


@lru_cache(maxsize=None)
def run(case: str) -> ClosureResult:
    """``close`` on the training run (k_out 20) with the other environment (k_out 35) held out."""
    form, c, T0, peak, (s_tr, s_te) = CASES[case]
    kw = dict(cubic_1_m2=c, T0_N=T0, peak_Nm=peak, declare_env=form == "testbed")
    tr, _ = distributed_run(SECONDS, seed=s_tr, k_out=20.0, b_out=2.0, source="train", **kw)
    te, _ = distributed_run(SECONDS, seed=s_te, k_out=35.0, b_out=1.5, source="test", **kw)
    sig = signals_from_tables([tr, te])
    return close(sig.take(sig.run_id == 0), sig.take(sig.run_id == 1))


def _clean_problems(case: str) -> list:
    res = run(case)
    r = res.targets[Target.TAU_OUT]
    assert res.dynamic is not None
    assert res.dynamic.fit.spec.form.name == CASES[case][0].upper()
    out = [(c.effect, round(c.improvement, 4)) for c in r.selected]
    if not r.rmse_before_Nm <= 0.05:
        out.append(("baseline", r.rmse_before_Nm))
    return out


def test_immaterial_testbed_baseline_at_the_floor_and_nothing_selected() -> None:
    assert _clean_problems("testbed_hardening") == []


@pytest.mark.xfail(strict=True, reason="measured 2026-11-28 (numpy 2.4.6 / scipy 1.17.1): the clean two-angle runs "
                                       "select nothing on 1 of 5 seed pairs (pretension_relaxation 0.41, "
                                       "empirical:T_up_in 0.32, a baseline above the floor 0.083 Nm, ...)")
def test_clean_two_angle_runs_select_nothing_at_the_stated_rate() -> None:
    problems = {case: _clean_problems(case) for case in _seeded("angles_clean")}
    assert sum(not p for p in problems.values()) >= RATE, problems


def test_two_angle_form_offers_the_stiffening_and_the_testbed_does_not() -> None:
    assert any(c.effect == "strain_stiffening" for c in run("angles_clean").targets[Target.TAU_OUT].candidates)
    assert not any(c.effect == "strain_stiffening" for c in run("testbed_hardening").targets[Target.TAU_OUT].candidates)


def test_fitted_stiffness_is_the_pairs_linearised_one() -> None:
    # 240 (1 + 3 c D0^2) with k_c D0 (1 + c D0^2) = T0 (the module docstring): the hardening
    # cable read as a stiffer linear one; the clean pair at 240 Nm/rad
    c, T0, k_c = 3e5, 80.0, 240.0 / (2 * 0.04 * 0.04)
    r = np.roots([k_c * c, 0.0, k_c, -T0])
    D0 = float(r[np.abs(r.imag) < 1e-9].real[0])
    K_lin = 240.0 * (1.0 + 3.0 * c * D0 * D0)
    assert run("angles_hardening").dynamic.fit.params["K_c_Nm_rad"] == pytest.approx(K_lin, rel=0.1)
    assert run("angles_clean").dynamic.fit.params["K_c_Nm_rad"] == pytest.approx(240.0, rel=0.1)


def _c_node_of_the_cable(c: float, T0: float) -> float:
    """``4 c r^2 / (1 + 3 c D0^2)`` with ``k_c D0 (1 + c D0^2) = T0`` (r 0.04 m, K_c 240 Nm/rad)."""
    k_c = 240.0 / (2 * 0.04 * 0.04)
    r = np.roots([k_c * c, 0.0, k_c, -T0])
    D0 = float(r[np.abs(r.imag) < 1e-9].real[0])
    return 4.0 * c * 0.04 ** 2 / (1.0 + 3.0 * c * D0 * D0)


def _hardening_problems(case: str) -> list:
    r = run(case).targets[Target.TAU_OUT]
    if not r.selected:
        return [f"nothing selected (baseline {r.rmse_before_Nm:.4f} Nm)"]
    first = r.selected[0]
    if not (first.effect == "strain_stiffening" and "deflection" in first.depends_on):
        return [(c.effect, c.depends_on) for c in r.selected]
    out = []
    if not 1.0 - r.rmse_after_Nm / r.rmse_before_Nm >= 0.30:
        out.append((r.rmse_before_Nm, r.rmse_after_Nm))
    _, c, T0, _, _ = CASES[case]
    if first.params["c_node_1_rad2"] != pytest.approx(_c_node_of_the_cable(c, T0), rel=0.25):
        out.append(("c_node", first.params["c_node_1_rad2"], _c_node_of_the_cable(c, T0)))
    if not (3.0 <= first.params["beta"] <= 9.0 and first.params["beta_plausible"]):
        out.append(("beta", first.params["beta"]))
    return out


@pytest.mark.xfail(strict=True, reason="measured 2026-11-28: traced on 3 of 5 seed pairs (pair 4 selects "
                                       "dwell_stiction before strain_stiffening)")
def test_hardening_traced_to_deflection_and_cuts_heldout_error_at_the_stated_rate() -> None:
    problems = {case: _hardening_problems(case) for case in _seeded("angles_hardening")}
    assert sum(not p for p in problems.values()) >= RATE, problems


def test_hardening_on_the_long_run_path(long_path: None) -> None:
    # the long-run path (baseline on windows finished on every sample, candidates screened on
    # windows) with its thresholds lowered so that these 15 s runs take it (conftest.long_path)
    from capstan.models.closure import windows
    for case in ("angles_clean", "angles_hardening"):
        res = run.__wrapped__(case)            # not the cached short-path result
        r = res.targets[Target.TAU_OUT]
        assert res.dynamic is not None and len(res.dynamic.y_train_Nm) > windows.WARM_START_SAMPLES
        assert r.rmse_before_Nm <= 0.05
        if case == "angles_clean":
            assert r.selected == [], [(c.effect, c.improvement) for c in r.selected]
        else:
            assert r.selected and r.selected[0].effect == "strain_stiffening"
            assert 1.0 - r.rmse_after_Nm / r.rmse_before_Nm >= 0.30, (r.rmse_before_Nm, r.rmse_after_Nm)
            assert r.selected[0].params["c_node_1_rad2"] == pytest.approx(_c_node_of_the_cable(3e5, 80.0), rel=0.25)


def main() -> None:
    """Print each case's figures (``python tests/test_closure_hardening.py``)."""
    for case in CASES:
        res = run(case)
        r = res.targets[Target.TAU_OUT]
        cut = 1.0 - r.rmse_after_Nm / r.rmse_before_Nm
        sel = ", ".join(f"{c.effect} ({'/'.join(c.depends_on)})" for c in r.selected) or "nothing"
        st = [f"round {c.round}: {-100 * c.improvement:+.1f} % (c_node {c.params['c_node_1_rad2']:.0f} 1/rad^2, "
              f"beta {c.params['beta']:.2f})"
              for c in r.candidates if c.effect == "strain_stiffening"]
        print(f"{case:18s} {res.dynamic.fit.spec.form.name:7s} K {res.dynamic.fit.params.get('K_c_Nm_rad', float('nan')):.0f} "
              f"{r.rmse_before_Nm:.4f} -> {r.rmse_after_Nm:.4f} Nm ({-100 * cut:+.1f} %)  selected: {sel}  "
              f"stiffening: {'; '.join(st) or 'not offered'}")
    _, c, T0, _, _ = CASES["angles_hardening"]
    print(f"c_node the cable maps to (c {c:g} 1/m^2, T0 {T0:g} N): {_c_node_of_the_cable(c, T0):.0f} 1/rad^2")


if __name__ == "__main__":
    main()
