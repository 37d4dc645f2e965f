"""Candidates are mechanisms, not second sensors of the target.

A signal that measures the predicted channel, or is tied to it algebraically, would
"explain" the residual by reading the answer (the output-side cable tensions give
``tau_out = r_out (T_up,out - T_lo,out)``; a drive current is ``tau_in`` through the motor
constant; the environment actuator's command sets ``tau_out``). Such signals are not
candidates; :func:`excluded_signals` lists them with the reason:

* declared: the import description marks the channel ``tied_to: tau_in | tau_out``;
* the target itself under another name (``load`` is tau_in);
* ``tension`` when it averages the target's own load cells (T_lc_in for tau_in, T_lc_out for
  tau_out): the common mode of the cells whose difference is the target;
* measured: on the training runs the target is a linear function of the signal
  (R^2 >= ``TIE_R2``) or of a pair of signals (R^2 >= ``PAIR_R2``);
* the same test against a driving torque channel: a second sensor of what drives the
  simulation (the input tensions beside tau_in) would take the credit for that
  channel's own error (a load-cell gain error is a property of ``load``).

The states of the motion (velocity, acceleration, position, dwell, time) and the
driving signals of the simulation are mechanisms by construction and never tested.
"""

from __future__ import annotations

import itertools

import numpy as np

from capstan.models.closure.signals import Signals

#: a single signal this linearly tied to the target is a second sensor of it
TIE_R2 = 0.95
#: a pair of signals this linearly tied to the target (e.g. two tensions) is one
PAIR_R2 = 0.99
#: rows used for the tie tests (every k-th sample)
MAX_ROWS = 200_000
#: never tested: states of the motion
MOTION = frozenset({"velocity", "acceleration", "position", "dwell", "time"})
#: candidate signal names of the driving channels
_DRIVING_SIGNAL = {"tau_in": "load", "q_in": "q_in", "q_out": "position", "tau_out": "tau_out"}


def _r2(X: np.ndarray, y: np.ndarray) -> float:
    A = np.column_stack([X, np.ones(X.shape[0])])
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    var = float(np.var(y))
    return 1.0 - float(np.mean((y - A @ coef) ** 2)) / var if var > 0.0 else 0.0


def excluded_signals(sig: Signals, target: str, driving: tuple[str, ...] = ()) -> dict[str, str]:
    """``{signal: reason}`` of the candidate signals of ``sig`` that are not mechanisms
    when predicting ``target`` (``"tau_in"`` or ``"tau_out"``) -- see the module docstring."""
    out: dict[str, str] = {}
    avail = sig.available()
    for name, tied in sig.tied_to.items():
        if name in avail:
            out[name] = f"declared in the import description as tied to {tied}"
    if target == "tau_in" and "load" in avail:
        out["load"] = "load is tau_in, the predicted channel"
    side = "in" if target == "tau_in" else "out"
    if "tension" in avail and side in sig.tension_sides:
        out["tension"] = (f"tension averages the {side}put-side load cells (T_lc_{side}), whose difference is {target}: "
                          "a second reading of the predicted channel's sensors")
    protected = MOTION | {_DRIVING_SIGNAL.get(d, d) for d in driving}
    ties = [(target, f"tied to {target}")]
    ties += [(d, f"a second sensor of the driving channel {d}") for d in driving if d in ("tau_in", "tau_out") and d != target]
    step = max(1, len(sig) // MAX_ROWS)
    for channel, why in ties:
        y = (sig.tau_in_Nm if channel == "tau_in" else sig.tau_out_Nm)[::step]
        test = []
        for name in avail:
            if name in out or name in protected:
                continue
            x = sig.signal(name)
            if x is None:
                continue
            xs = x[::step]
            r2 = _r2(xs[:, None], y)
            if r2 >= TIE_R2:
                out[name] = f"{why}: a linear function of it explains {100 * r2:.1f} % of {channel}'s variance"
            else:
                test.append((name, xs))
        for (n1, x1), (n2, x2) in itertools.combinations(test, 2):
            r2 = _r2(np.column_stack([x1, x2]), y)
            if r2 >= PAIR_R2:
                for a, b in ((n1, n2), (n2, n1)):
                    out.setdefault(a, f"{why} together with {b}: a linear function of the pair explains "
                                      f"{100 * r2:.2f} % of {channel}'s variance")
    return out
