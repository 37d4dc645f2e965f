"""``close`` on runs of the *independent* plant (tests/independent_plant.py: written from the
paper, no package code; tests/independent_runs.py: a motor-driven rig, 12 nodes per cable on a
two-bend curvature profile, the testbed output, sensors with noise and quantisation) with
effects written in that module's own forms, never the closure catalogue's:

=================  ==================================================  =======================
effect             physics (tests/independent_runs.py)                 the right mechanism
=================  ==================================================  =======================
dwell_load         node junction ageing under a held torque, erased    dwell_stiction
                   by 0.1 mm of node slip
node_drag          c2 v|v| in every node's own sliding speed (5000)           speed_viscous
reroute_step       the second bend 50 % tighter from mid-run           a friction capacity
                                                                       over time:
                                                                       pretension_relaxation
                                                                       or empirical:time
relaxation         pretension field x (1 - 0.35 (1 - exp(-t / 4 s)))   pretension_relaxation
load_cell_gain     both input load cells 6 % high                      drive_gain (+6 %)
=================  ==================================================  =======================

Training run k_out 20 / b_out 2, held-out run k_out 35 / b_out 1.5 (another environment),
8 s each at 1 kHz. Five seed pairs per case, all kept; the claim is a rate:

* clean runs: nothing selected on >= 4 of 5, baseline held-out RMSE <= 0.05 Nm on all
  (the noise floor is ~0.03 Nm: torque sensor 0.02 Nm, load cells 0.5 N);
* each effect: the *first* selected explanation is the mechanism's (the effect's name, not
  only its signal) and cuts the held-out RMSE by >= 30 %, on >= 4 of 5 seed pairs;
* the load-cell gain: measured as 0.06 +- 0.006 on >= 4 of 5.

Where the closure falls short today the case is ``xfail(strict=True)`` with the measured
figures (issue #30: dwell under load, drag vs sensor delay, step vs ramp), so that a fix
shows up as an XPASS. ``python -m tests.test_closure_families_independent [EFFECT ...]`` prints the table.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest

from capstan.models.closure.effects import Target
from capstan.models.closure.pipeline import close
from capstan.models.closure.scoring import TargetResult
from capstan.models.closure.signals import signals_from_tables
from tests.independent_runs import rig_run

pytestmark = pytest.mark.slow

SECONDS = 8.0
SEEDS = (0, 1, 2, 3, 4)
#: right on at least this many of the five seed pairs
RATE = 4
CUT = 0.30

#: effect -> the effect names that are its mechanism (module docstring)
MECHANISM = {
    "dwell_load": {"dwell_stiction"},
    "node_drag": {"speed_viscous"},
    "reroute_step": {"pretension_relaxation", "empirical:time"},
    "relaxation": {"pretension_relaxation"},
    "load_cell_gain": {"drive_gain"},
}

#: measured shortfalls (``main()``'s table, 2026-11-28; the figures are the reason)
SHORT: dict[str, str] = {
    "dwell_load": "right on 1 of 5 (dwell_stiction, -59 %); nothing selected on 4 at held-out RMSE "
                  "0.047-0.162 Nm (issue #30: dwell under load)",
    "reroute_step": "right on 1 of 5 (empirical:time, -64 %); nothing on 2 (0.19-0.27 Nm), empirical:acceleration "
                    "-34 %, empirical:time +25 % (issue #30: a step is not a ramp)",
    "relaxation": "right on 0 of 5: nothing selected on 4 at held-out RMSE 0.15-0.19 Nm; empirical:time -66 % "
                  "on 1 (a description over time, not pretension_relaxation)",
    "node_drag": "right on 0 of 5: nothing selected on 4 at held-out RMSE 0.042-0.059 Nm (clean: 0.026-0.029); "
                 "empirical:velocity -57 % on 1 (the signal, not speed_viscous)",
}


@lru_cache(maxsize=None)
def closed(effect: str, seed: int) -> TargetResult:
    """``close`` on seed pair ``seed``: training (k_out 20) and held-out (k_out 35) runs."""
    tr, _ = rig_run(effect, 2 * seed + 1, 20.0, 2.0, SECONDS, source="train")
    te, _ = rig_run(effect, 2 * seed + 2, 35.0, 1.5, SECONDS, source="test")
    sig = signals_from_tables([tr, te])
    return close(sig.take(sig.run_id == 0), sig.take(sig.run_id == 1)).targets[Target.TAU_OUT]


def cut(r: TargetResult) -> float:
    return 1.0 - r.rmse_after_Nm / r.rmse_before_Nm


def right(effect: str, r: TargetResult) -> bool:
    """The first selected explanation is the effect's mechanism and cuts >= 30 %."""
    return bool(r.selected) and r.selected[0].effect in MECHANISM[effect] and cut(r) >= CUT


def _describe(r: TargetResult) -> str:
    sel = ", ".join(c.effect for c in r.selected) or "nothing"
    return f"{r.rmse_before_Nm:.3f}->{r.rmse_after_Nm:.3f} Nm ({-100 * cut(r):+.0f} %) {sel}"


def test_clean_runs_select_nothing_at_the_noise_floor() -> None:
    res = [closed("none", s) for s in SEEDS]
    assert max(r.rmse_before_Nm for r in res) <= 0.05, [_describe(r) for r in res]
    assert sum(not r.selected for r in res) >= RATE, [_describe(r) for r in res]


@pytest.mark.parametrize("effect", [pytest.param(e, marks=pytest.mark.xfail(strict=True, reason=SHORT[e]))
                                    if e in SHORT else e for e in MECHANISM])
def test_the_effect_is_named_for_its_mechanism_and_cuts_heldout_error(effect: str) -> None:
    res = [closed(effect, s) for s in SEEDS]
    assert sum(right(effect, r) for r in res) >= RATE, [_describe(r) for r in res]


def test_the_load_cell_gain_is_measured_as_injected() -> None:
    got = []
    for s in SEEDS:
        sel = closed("load_cell_gain", s).selected
        got.append(sel[0].params.get("load_cell_gain_error", np.nan) if sel and sel[0].effect == "drive_gain"
                   else np.nan)
    assert sum(abs(g - 0.06) <= 0.006 for g in got) >= RATE, got


def test_a_step_in_routing_described_over_time_is_called_a_step_with_its_interval() -> None:
    """Where the re-routing is explained by an empirical curve over time, its words name a step
    up (the tighter bend adds friction from one instant on), and the stated peak-to-peak -- over
    the 5-95 % support of the run time -- lies inside its bootstrap interval (issue #30: it was
    "rises about linearly")."""
    described = [r.selected[0] for r in (closed("reroute_step", s) for s in SEEDS)
                 if r.selected and r.selected[0].effect == "empirical:time"]
    assert described, "no seed pair explained the re-routing by a curve over time"
    for c in described:
        d = c.description
        assert d is not None and "steps up" in d["trend"], d
        lo, hi = d["peak_to_peak_Nm_interval"]
        assert lo <= d["peak_to_peak_Nm"] <= hi, d
        assert d["support"][0] >= 0.05 * SECONDS * 0.99 and d["support"][1] <= 0.95 * SECONDS * 1.01, d["support"]


def main(effects: list[str]) -> None:
    """Print every case's figures, seed by seed (all cases if ``effects`` is empty)."""
    for effect in effects or ("none", *MECHANISM):
        for s in SEEDS:
            r = closed(effect, s)
            ok = "" if effect == "none" else ("right" if right(effect, r) else "WRONG")
            print(f"{effect:15s} seed {s}  {_describe(r)}  {ok}", flush=True)


if __name__ == "__main__":
    import sys
    main(sys.argv[1:])
