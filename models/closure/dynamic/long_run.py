"""In-model candidates on long runs (more than ``windows.WARM_START_SAMPLES`` training
samples, e.g. an hour at 1 kHz).

The search of :class:`capstan.models.closure.dynamic.in_model.InModelCloser` (each shape of a
candidate's grid by Powell's method, the baseline held: hundreds of simulations per
candidate) costs minutes on millions of samples. On long runs instead:

1. *screen* -- each candidate's coefficients, for every shape of its grid, by one bounded
   Levenberg-Marquardt step from zero (``REFINE_ITERS`` more at the chosen shape when it
   screens in) (:mod:`capstan.models.common.projected_lm`; difference
   steps of ``COEF_STEP`` of the capacity or drive scale, where a stick-slip output error is
   smooth enough to be linearised), the baseline and the effects already selected held, on
   the training windows (:mod:`capstan.models.closure.windows`); the shape with the lowest
   windowed training error is the candidate's;
2. where it lowers the training windows' RMSE by at least ``SCREEN_MIN`` (half the
   materiality) the caller scores it on every held-out sample, as for short runs; otherwise
   it is reported as screened out (it does not help even where it was fitted), unscored;
3. *joint refit* of the winner with the baseline's free parameters: Levenberg-Marquardt on
   the windows from the screened coefficients, then ``JOINT_FINAL_ITERS`` step(s) on every
   training sample; the joint fit is kept only where it lowers the every-sample training
   error below that of the effect with the baseline held (the rule of ``refit``).
"""

from __future__ import annotations

import math

import numpy as np

from capstan.models.closure.dynamic.baseline import DIFF_STEP, _predict, _velocity_scale
from capstan.models.closure.dynamic.in_model import InModelCloser, JointFit
from capstan.models.closure.dynamic.candidates import InModelEffect
from capstan.models.closure.effects import shift_within_runs
from capstan.models.common.projected_lm import projected_lm
from capstan.models.closure import windows

#: difference step of a dimensionless effect coefficient (a share of the friction capacity
#: or of the drive scale); the drag coefficient's is the drag giving that share at the
#: run's 95th-percentile speed
COEF_STEP = 0.05
#: Levenberg-Marquardt steps of the screen (per shape), of the joint refit on the windows,
#: and of the joint refit on every sample
SCREEN_ITERS = 1
JOINT_WINDOW_ITERS = 3
JOINT_FINAL_ITERS = 1
#: damping trials of a screening step (each one simulation of the windows)
SCREEN_TRIALS = 2
#: Levenberg-Marquardt steps refining a candidate that screens in (at its chosen shape)
REFINE_ITERS = 6
#: a candidate is scored on every held-out sample when it lowers the training windows' RMSE by this
SCREEN_MIN = 0.025


class LongRunCloser:
    """Screening and joint refits of in-model candidates on long runs (module docstring).

    :param closer: the closer on every sample of the training and held-out runs.
    :param max_samples: samples of the training windows (default ``windows.SCREEN_SAMPLES``).
    :raises ModelError: if the runs carry no motion.
    """

    def __init__(self, closer: InModelCloser, max_samples: int | None = None) -> None:
        self.closer = closer
        m = windows.SCREEN_SAMPLES if max_samples is None else max_samples
        self.win = InModelCloser(closer.dyn, closer.train.take(windows.window_index(closer.train, m,
                                                                                    windows.SCREEN_WINDOW_S)),
                                 closer.test)
        v95 = _velocity_scale(closer.train, closer.form)
        tau_fc = max(float(closer.dyn.params.get("tau_fc_Nm", 0.0)), 1e-6)
        self._c2_step = COEF_STEP * tau_fc / (v95 * v95)
        self._round: tuple[JointFit, np.ndarray, np.ndarray, float] | None = None

    def _current(self, current: JointFit) -> tuple[np.ndarray, np.ndarray, float]:
        """(training-window residual, its prediction without the current lag, the current lag
        [s]) of the current model, simulated once per round."""
        if self._round is None or self._round[0] is not current:
            cl = self.win
            mods = current.mods(cl.train)
            lag = mods.lag_s
            mods.lag_s = 0.0
            p_nolag = _predict(cl.form, current.base, cl.train, cl.dyn.declared_env, mods)[0]
            r_tr = shift_within_runs(p_nolag, cl.train, lag) - cl.y
            self._round = (current, r_tr, p_nolag, lag)
        return self._round[1], self._round[2], self._round[3]

    def held_out(self, jf: JointFit, improvement_train: float) -> np.ndarray | None:
        """``jf``'s prediction on every held-out sample, or None when the candidate is screened
        out: its training-window RMSE improvement (from :meth:`candidate`) is below
        ``SCREEN_MIN`` (it does not even help where it was fitted).

        :raises ModelError: if a simulation fails.
        """
        if improvement_train < SCREEN_MIN:
            return None
        return self.closer.predict(jf, test=True)

    def _steps(self, eff: InModelEffect) -> np.ndarray:
        return np.array([self._c2_step if n.startswith("C2") else COEF_STEP for n in eff.coef_names])

    def candidate(self, current: JointFit, eff: InModelEffect) -> tuple[dict, JointFit, float]:
        """(shape, fit, RMSE improvement on the training windows) of ``eff``, fitted on the
        training windows with the current model held.

        :raises ModelError: if a simulation fails.
        """
        cl = self.win
        k = len(eff.coef_names)
        steps = self._steps(eff)
        lo, hi = np.array(eff.lo, float), np.array(eff.hi, float)
        r0, p_nolag, lag0 = self._current(current)
        sse0 = float(np.dot(r0, r0))

        def model(c: np.ndarray, sh: dict) -> JointFit:
            return JointFit(current.base, list(current.effects) + [(eff, sh, c)])

        def resid_at(sh: dict):
            return lambda c: cl.predict(model(c, sh), test=False) - cl.y

        best: tuple[float, dict, np.ndarray, np.ndarray] | None = None
        for sh in eff.grid:
            if k == 0:     # a lag only moves the prediction: no simulation
                lag = lag0 + eff.mods(cl.train, sh, np.zeros(0)).lag_s
                c, r = np.zeros(0), shift_within_runs(p_nolag, cl.train, lag) - cl.y
            else:
                res = projected_lm(resid_at(sh), np.zeros(k), lo, hi, steps, SCREEN_ITERS, DIFF_STEP,
                                   abs_step=steps, r0=r0, max_trials=SCREEN_TRIALS)
                c, r = res.x, res.r
            sse = float(np.dot(r, r))
            if best is None or sse < best[0]:
                best = (sse, sh, c, r)
        assert best is not None
        sse, sh, c, r = best
        if k and sse0 > 0.0 and 1.0 - math.sqrt(sse / sse0) >= SCREEN_MIN:
            # worth scoring: its coefficients refined at the chosen shape
            res = projected_lm(resid_at(sh), c, lo, hi, steps, REFINE_ITERS, DIFF_STEP, abs_step=0.2 * steps,
                               r0=r)
            c, sse = res.x, 2.0 * res.cost
        imp = 1.0 - math.sqrt(sse / sse0) if sse0 > 0.0 else 0.0
        return sh, model(c, sh), imp

    def joint_pair(self, current: JointFit, eff: InModelEffect) -> tuple[JointFit, list[JointFit], float]:
        """(``eff`` at its one shape refitted with the baseline's free parameters, the models
        without it it is scored against, the first's RMSE improvement over the better of those
        on the training windows) -- :meth:`InModelCloser.joint_pair` on long runs:
        ``JOINT_WINDOW_ITERS`` Levenberg-Marquardt steps on the training windows, from the
        current model with ``eff``'s coefficients at 0, from the current model without ``eff``,
        and from the joint refit's baseline without ``eff``.

        :raises ModelError: if a simulation fails.
        """
        cl = self.win
        nb = int(np.count_nonzero(cl.free))
        steps = 0.2 * self._steps(eff)

        def lm(start: JointFit, e: InModelEffect | None) -> tuple[JointFit, float]:
            k = len(eff.coef_names) if e is not None else 0
            pf0 = start.base[cl.free]
            x0 = np.concatenate([pf0, np.zeros(k)])
            lo = np.concatenate([cl.lo, np.array(eff.lo, float)[:k]])
            hi = np.concatenate([cl.hi, np.array(eff.hi, float)[:k]])
            scale = np.concatenate([np.maximum(np.abs(pf0), 1e-6), steps[:k]])
            abs_step = np.concatenate([np.full(nb, np.nan), steps[:k]])

            def model(x: np.ndarray) -> JointFit:
                return JointFit(cl._full(x[:nb]), list(current.effects) + ([(e, e.grid[0], x[nb:])] if e else []))

            res = projected_lm(lambda x: cl.predict(model(x), test=False) - cl.y, x0, lo, hi, scale,
                               JOINT_WINDOW_ITERS, DIFF_STEP, abs_step=abs_step)
            return model(res.x), 2.0 * res.cost

        jf, sse = lm(current, eff)
        refs = [lm(current, None), lm(JointFit(jf.base, list(current.effects)), None)]
        sse_ref = min(e for _, e in refs)
        imp = 1.0 - math.sqrt(sse / sse_ref) if sse_ref > 0.0 else 0.0
        return jf, [m for m, _ in refs], imp

    def joint(self, current: JointFit, eff: InModelEffect, shape: dict, coef: np.ndarray) -> JointFit:
        """``eff`` at ``shape`` refitted with the baseline's free parameters (windows, then
        every training sample), or with the baseline held where that fits better.

        :raises ModelError: if a simulation fails.
        """
        full = self.closer
        held = JointFit(current.base, list(current.effects) + [(eff, shape, np.asarray(coef, float))])
        pf0 = current.base[full.free]
        nb = pf0.size
        x0 = np.concatenate([pf0, coef])
        lo = np.concatenate([full.lo, np.array(eff.lo, float)])
        hi = np.concatenate([full.hi, np.array(eff.hi, float)])
        steps = 0.2 * self._steps(eff)
        scale = np.concatenate([np.maximum(np.abs(pf0), 1e-6), np.maximum(steps, np.abs(coef))])
        abs_step = np.concatenate([np.full(nb, np.nan), steps])

        def model(cl: InModelCloser, x: np.ndarray) -> JointFit:
            return JointFit(cl._full(x[:nb]), list(current.effects) + [(eff, shape, x[nb:])])

        def resid_on(cl: InModelCloser):
            return lambda x: cl.predict(model(cl, x), test=False) - cl.y

        w = projected_lm(resid_on(self.win), x0, lo, hi, scale, JOINT_WINDOW_ITERS, DIFF_STEP, abs_step=abs_step)
        f = projected_lm(resid_on(full), w.x, lo, hi, scale, JOINT_FINAL_ITERS, DIFF_STEP, abs_step=abs_step)
        r_h = full.predict(held, test=False) - full.y
        if float(np.dot(r_h, r_h)) <= 2.0 * f.cost:
            return held
        return model(full, f.x)
