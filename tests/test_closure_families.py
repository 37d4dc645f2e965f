"""Evidence from another model family: ``capstan close`` on testbed runs of the distributed
model (N = 12, double-bend non-uniform curvature, eq-23 pretension field, noise 0.02 Nm on
the torques and 1e-3 rad/s on dq_out, all four fixture tensions as channels, recorded from
a plant at rest: the model settles before the recording starts), training and
held-out runs in different environments (k_out 20 / 35 Nm/rad), with effects injected
into *that* physics in forms other than the closure catalogue's (tests/closure_plants.py):

* bending that grows with the joint angle (node friction x (1 + 3 |q_out|));
* creep of the pretension (every segment -60 N (1 - exp(-t / 15 s)));
* the output torque sensor 20 ms late;
and three the catalogue does not have:
* an eccentric input pulley (the cable sees the drive torque x (1 + 0.08 sin(3 q_in + 0.5)));
* a gain error of the input load cell (+6 %);
* direction-dependent sheath friction (node friction x 1.3 while dq_out > 0).

Clean runs: baseline held-out RMSE <= 0.05 Nm and nothing selected. Each effect: the
first selected explanation is the injected mechanism (the candidate that can express it:
:data:`MECHANISM`; an explanation that merely shares its signal, e.g. friction over the
output angle for a gain over the input pulley's angle, does not pass), and the held-out
RMSE falls by >= 30 %. Effects the closure does not yet meet that bar on are marked
``xfail(strict=True)`` with the measured figures, so a fix shows up as an XPASS.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest

from capstan.models.closure.effects import Target
from capstan.models.closure.pipeline import ClosureResult, close
from capstan.models.closure.signals import signals_from_tables

from closure_plants import Injection, distributed_run

pytestmark = pytest.mark.slow

SECONDS = 15.0


def _shift(x: np.ndarray, k: int) -> np.ndarray:
    return np.concatenate([np.full(k, x[0]), x[:-k]])


def _late_tau_out(cols: dict) -> None:
    cols["tau_out"] = _shift(cols["tau_out"], 20)


def _gain_tau_in(cols: dict) -> None:
    cols["tau_in"] = 1.06 * cols["tau_in"]


INJECT = {
    "none": Injection(),
    "bending_with_angle": Injection(mu=lambda t, m, s: np.full(2 * m.n, 1.0 + 3.0 * abs(m.q_out_rad))),
    "pretension_creep": Injection(creep=lambda t: -60.0 * (1.0 - np.exp(-t / 15.0))),
    "late_tau_out": Injection(post=_late_tau_out),
    "eccentric_input": Injection(u=lambda t, m, s: 1.0 + 0.08 * np.sin(3.0 * m.q_in_rad + 0.5)),
    "load_cell_gain": Injection(post=_gain_tau_in),
    "direction_asymmetry": Injection(mu=lambda t, m, s: np.full(2 * m.n, 1.3 if m.dq_out_rad_s > 0 else 1.0)),
}

#: injected effect -> the signals an explanation may name (the mechanism's own)
SIGNAL = {
    "bending_with_angle": {"position"},
    "pretension_creep": {"time"},
    "late_tau_out": {"latency"},
    "eccentric_input": {"q_in"},
    "load_cell_gain": {"load"},
    "direction_asymmetry": {"velocity"},
}

#: injected effect -> the candidates that express its mechanism (catalogued form or empirical curve):
#: friction growing with the joint angle; pretension falling with time; a late channel; a drive gain
#: over the input pulley's angle; a constant drive gain; friction that differs with the direction
#: (an even function of the velocity, as a curve over the direction or the velocity: the catalogue's odd drag
#: cannot express it; measured 2026-11-28: empirical:direction first, 0.2002 -> 0.0357 Nm)
MECHANISM = {
    "bending_with_angle": {"position_friction", "empirical:position"},
    "pretension_creep": {"pretension_relaxation", "empirical:time"},
    "late_tau_out": {"sensor_latency"},
    "eccentric_input": {"empirical:q_in"},
    "load_cell_gain": {"drive_gain"},
    "direction_asymmetry": {"empirical:direction", "empirical:velocity"},
}

#: measured shortfalls (see the module docstring)
SHORT: dict[str, str] = {
    # measured 2026-11-28 with numpy 2.4.6 / scipy 1.17.1 / numba 0.68.1 (the same on the code before this
    # change): the closure selects nothing, held-out 0.2217 Nm before and after (the README's earlier figure,
    # position_friction first, was measured with older package versions)
    "bending_with_angle": "nothing selected: held-out tau_out 0.2217 Nm before and after",
    # README "Closing the loop" table (seed pair 1/2): position_friction first, 0.082 -> 0.049 Nm (-40 %); the
    # mechanism's own candidate, empirical:q_in (the drive gain over q_in), scored 28 % against 26 % and lost
    # to the catalogue-first rule (0.26 >= 0.7 x 0.28). Friction over the output angle is not a gain over the
    # input pulley's angle: until the closure tells them apart this case falls short.
    "eccentric_input": "position_friction (friction over q_out) selected before empirical:q_in, the eccentric "
                       "pulley's gain over q_in (26 % vs 28 %, catalogue first at 0.7)",
}


def close_runs(effect: str) -> ClosureResult:
    """``close`` on the training run (k_out 20) with the other environment (k_out 35) held out."""
    inj = INJECT[effect]
    tr, _ = distributed_run(SECONDS, seed=1, k_out=20.0, b_out=2.0, source="train", inject=inj)
    te, _ = distributed_run(SECONDS, seed=2, k_out=35.0, b_out=1.5, source="test", inject=inj)
    sig = signals_from_tables([tr, te])
    return close(sig.take(sig.run_id == 0), sig.take(sig.run_id == 1))


@lru_cache(maxsize=None)
def run(effect: str) -> ClosureResult:
    return close_runs(effect)


def test_clean_runs_baseline_at_the_noise_floor_and_nothing_selected() -> None:
    res = run("none")
    r = res.targets[Target.TAU_OUT]
    assert res.dynamic is not None and res.dynamic.fit.spec.target == "tau_out"
    assert r.rmse_before_Nm <= 0.05
    assert r.selected == [], [(c.effect, c.improvement, c.ci_low) for c in r.selected]
    # the output tensions measure tau_out: never candidates
    assert {"T_up_out", "T_lo_out"} <= set(res.dynamic.excluded)


@pytest.mark.parametrize("effect", [pytest.param(e, marks=pytest.mark.xfail(strict=True, reason=SHORT[e]))
                                    if e in SHORT else e for e in sorted(SIGNAL)])
def test_injected_effect_is_traced_to_its_signal_and_cuts_heldout_error(effect: str) -> None:
    res = run(effect)
    r = res.targets[Target.TAU_OUT]
    assert r.selected, f"{effect}: nothing selected (baseline {r.rmse_before_Nm:.4f} Nm)"
    assert r.selected[0].effect in MECHANISM[effect], [(c.effect, c.depends_on) for c in r.selected]
    assert set(r.selected[0].depends_on) & SIGNAL[effect], [(c.effect, c.depends_on) for c in r.selected]
    assert 1.0 - r.rmse_after_Nm / r.rmse_before_Nm >= 0.30, (r.rmse_before_Nm, r.rmse_after_Nm)


def test_the_load_cell_gain_is_measured_as_injected() -> None:
    """The in-model drive gain (joint refit with the baseline) gives the simulation's drive
    1 / 1.06 of the measured tau_in: the injected error, which the closure never sees."""
    r = run("load_cell_gain").targets[Target.TAU_OUT]
    first = r.selected[0]
    assert first.effect == "drive_gain", [(c.effect, c.improvement) for c in r.selected]
    assert first.params["load_cell_gain_error"] == pytest.approx(0.06, abs=0.006)
    assert not first.implausible


def main() -> None:
    """Print each case's figures (``python tests/test_closure_families.py``): held-out RMSE
    before and after, and the selected effects in order."""
    for effect in ["none", *sorted(SIGNAL)]:
        r = run(effect).targets[Target.TAU_OUT]
        cut = 1.0 - r.rmse_after_Nm / r.rmse_before_Nm
        sel = ", ".join(f"{c.effect} ({'/'.join(c.depends_on)})" for c in r.selected) or "nothing"
        gain = [c for c in r.selected if c.effect == "drive_gain"]
        extra = f"  load-cell gain error {100 * gain[0].params['load_cell_gain_error']:+.2f} %" if gain else ""
        print(f"{effect:22s} {r.rmse_before_Nm:.4f} -> {r.rmse_after_Nm:.4f} Nm ({-100 * cut:+.1f} %)  selected: {sel}{extra}")


if __name__ == "__main__":
    main()
