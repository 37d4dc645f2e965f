"""The closure's dynamic baseline: the paper's reduced model (eqs 14-21, eq-25 averaged
pretension in ``tau_fc``) simulated through each whole run with friction as a state
(:mod:`capstan.models.transmission.stick_slip`), fitted by nonlinear least squares on the
simulation (output error).

The two cables of the pull-pull pair carry equal and opposite tension changes about the
averaged pretension, so their two torsional units (one per cable, stiffness ``K_c`` each
referred to the joint, capacity ``tau_fc / 2`` each) move together and are simulated as
one unit of stiffness ``2 K_c`` per side and capacity ``tau_fc``.

Driving forms: :mod:`capstan.models.closure.dynamic.forms`.

Parameters are bounded to the physical domain (``tau_fc >= 0``, stiffnesses > 0,
``zeta_s >= zeta_c = 1``, ``eta_s > 0``, ``b_vis >= 0``); one that ends at a bound or outside
its plausible range is listed in :attr:`DynamicFit.at_bound` / :attr:`DynamicFit.implausible`.
Uncertainties: block-sandwich covariance of the output-error Jacobian.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from capstan.models.closure.dynamic.forms import (INPUT_PREDICTED, PARAM_NAMES, DrivingForm, FormSpec, choose_form,
                                                  param_vector)
from capstan.models.closure.effects import shift_within_runs
from capstan.models.closure.identification import fit_elastic, sandwich_cov
from capstan.models.common.projected_lm import projected_lm
from capstan.models.closure.signals import Signals, derivative
from capstan.models.closure import windows
from capstan.models.common.errors import ModelError
from capstan.models.transmission.hardening import simulate_unit_hardening
from capstan.models.transmission.stick_slip import simulate_unit
from capstan.models.transmission.unit_plausibility import plausibility, split_by_uncertainty

#: Savitzky-Golay window of the input-angle derivative [s]
VELOCITY_WINDOW_S = 0.025
#: starting presliding travel (capacity / k_pre) as a fraction of the run's angle span
PRESLIDE_FRACTION = 1e-4
#: least-squares evaluations of the simulation per start
MAX_NFEV = 60
#: starting stiction ratio
ZETA_S0 = 1.05
#: relative finite-difference step of the Jacobian (wide: stick-slip switching makes the
#: output error piecewise smooth in the parameters)
DIFF_STEP = 1e-2
#: a time gap inside a run longer than this restarts the simulation from the measured state [s]
RESTART_GAP_S = 1.0
#: Levenberg-Marquardt steps on every sample after the fit on windows (long runs)
FINAL_ITERS = 1
#: start and lower bound of the friction law's exponent (input-predicted forms; 1 = Dahl)
DAHL_EXP0 = 2.0
DAHL_EXP_MIN = 0.05
DAHL_EXP_MAX = 4.0
#: start of the elastic path's damping as a time constant d_in / K_in [s] (LINK form)
D_IN_TAU0_S = 0.005


@dataclass
class DynamicFit:
    """A fitted dynamic baseline.

    :ivar params: named parameters (SI; ``zeta_s`` dimensionless).
    :ivar stderr: standard errors (block sandwich), same keys.
    :ivar at_bound: parameters that ended on a bound of the physical domain.
    :ivar implausible: ``{name: reason}`` for parameters outside their plausible range even with
        their uncertainty (1.96 standard errors); those outside only within it are in ``warnings``.
    :ivar undetermined: parameters whose standard error exceeds their magnitude (the data
        do not determine them; e.g. a stiffness in series with a softer presliding one).
    :ivar warnings: data findings stated in the report (e.g. a negative mean input power:
        the torque and angle sign conventions disagree).
    :ivar rmse_Nm: training RMSE on the target [Nm].
    """

    spec: FormSpec
    params: dict[str, float]
    stderr: dict[str, float] = field(default_factory=dict)
    at_bound: list[str] = field(default_factory=list)
    implausible: dict[str, str] = field(default_factory=dict)
    undetermined: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    rmse_Nm: float = math.nan
    n_samples: int = 0
    nfev: int = 0
    #: the environment of the TESTBED form is the runs' declared one (per run), not fitted
    declared_env: bool = False
    #: the target predicted on every training sample at the fitted parameters [Nm]
    pred_train_Nm: np.ndarray | None = field(default=None, repr=False)

    def predict(self, sig: Signals) -> np.ndarray:
        """The target channel predicted on ``sig`` [Nm] (every sample, runs separately).

        :raises ModelError: if the simulation fails or ``sig`` lacks a driving channel.
        """
        return self.predict_both(sig)[0]

    def predict_both(self, sig: Signals) -> tuple[np.ndarray, np.ndarray | None]:
        """(target, the other torque or None) predicted on ``sig`` [Nm]."""
        return _predict(self.spec.form, param_vector(self.spec.form, self.params), sig, self.declared_env)


def _starts(sig: Signals) -> np.ndarray:
    """First sample of each simulated stretch, then ``len(sig)``: each run's start, and inside
    a run the first sample after a gap longer than ``RESTART_GAP_S`` (the state through the
    gap is unknown: the simulation restarts from the measured state, as at a run's start)."""
    cuts = [a for a, _ in sig.segments()]
    if len(sig) > 1:
        cuts.extend((np.flatnonzero(np.diff(sig.t_s) > RESTART_GAP_S) + 1).tolist())
    return np.array(sorted(set(cuts)) + [len(sig)], dtype=np.int64)


@dataclass
class Mods:
    """Effects acting inside the simulation (:mod:`capstan.models.closure.dynamic.candidates`).

    :ivar cap_scale: per-sample multiplier of the friction capacity (clipped at 0), or None.
    :ivar drive_Nm: per-sample torque added to the torque balance's drive [Nm], or None.
    :ivar c2_Nms2_rad2: drag ``c2 v |v|`` at speed.
    :ivar lag_s: the target measured this late (negative: the driving channels late) [s].
    :ivar c_node_1_rad2: strain hardening of the unit's cable paths ``K e (1 + c_node e^2)``
        [1/rad^2] (:mod:`capstan.models.transmission.hardening`; not in the TESTBED form,
        whose unit has no cable path).
    """

    cap_scale: np.ndarray | None = None
    drive_Nm: np.ndarray | None = None
    c2_Nms2_rad2: float = 0.0
    lag_s: float = 0.0
    c_node_1_rad2: float = 0.0
    #: multiplier of the cable path's linear stiffness (K_in; K_h) -- the stiffening candidate
    #: keeps the path's mean stiffness with it (:mod:`capstan.models.closure.dynamic.candidates`)
    k_scale: float = 1.0


def _predict(form: DrivingForm, p: np.ndarray, sig: Signals,
             declared_env: bool, mods: Mods | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Simulate ``sig`` with parameter vector ``p`` (and effects ``mods``): (target, other torque or None)."""
    n = len(sig)
    mods = mods or Mods()
    starts = _starts(sig)
    x, v, fr = np.empty(n), np.empty(n), np.empty(n)
    rho = sig.ratio_q
    dahl_exp = 1.0
    if form in INPUT_PREDICTED:
        K, g, tfc, kp, zs, eta, bv, c_in, dahl_exp, d_in = p
        if mods.k_scale != 1.0:
            K = K * mods.k_scale
        if sig.q_in_rad is None:
            raise ModelError(f"the {form.name} form needs q_in")
        a = K * sig.q_in_rad - g * sig.tau_out_Nm
        x0 = a[starts[:-1]] / K
        dq_in = input_velocity(sig) if d_in != 0.0 else np.zeros(n)
        a = a + d_in * dq_in
        c0, kx = d_in, K
    elif form == DrivingForm.TESTBED:
        kout, bout, tfc, kp, zs, eta, bv, c_out = p
        a = rho * sig.tau_in_Nm
        x0 = sig.q_out_rad[starts[:-1]].copy()
        if declared_env:
            if sig.environment is None:
                raise ModelError("the baseline was fitted with a declared output environment; these runs declare none")
            env = sig.environment[starts[:-1]]
            c0, kx = env[:, 1].copy(), env[:, 0].copy()
            kout, bout = sig.environment[:, 0], sig.environment[:, 1]
        else:
            c0, kx = bout, kout
    else:
        Kc, tfc, kp, zs, eta, bv, c_in, c_out = p
        if sig.q_in_rad is None:
            raise ModelError("the ANGLES form needs q_in")
        Kh = 2.0 * Kc
        if mods.k_scale != 1.0:
            Kh = Kh * mods.k_scale
        a = Kh * (sig.q_in_rad + rho * sig.q_out_rad)
        # the node where the output half carries the measured tau_out (the state the friction
        # holds; a restart inside a motion, e.g. a long run's window, is not at zero friction)
        s0 = starts[:-1]
        x0 = rho * sig.q_out_rad[s0] + (sig.tau_out_Nm[s0] - c_out) / (rho * Kh)
        c0, kx = 0.0, 2.0 * Kh
    if mods.drive_Nm is not None:
        a = a + mods.drive_Nm
    cap = np.empty(0) if mods.cap_scale is None else np.ascontiguousarray(np.maximum(mods.cap_scale, 0.0))
    nr = starts.shape[0] - 1
    c0_r = np.broadcast_to(np.asarray(c0, dtype=np.float64), (nr,)).copy()
    kx_r = np.broadcast_to(np.asarray(kx, dtype=np.float64), (nr,)).copy()
    ch = float(mods.c_node_1_rad2)
    if ch == 0.0:
        done = simulate_unit(sig.t_s, np.ascontiguousarray(a, dtype=np.float64), starts, np.asarray(x0, np.float64),
                             c0_r, kx_r, float(kp), float(tfc), float(zs), float(eta), float(bv), x, v, fr, cap,
                             float(mods.c2_Nms2_rad2), float(dahl_exp))
    else:
        if form == DrivingForm.TESTBED:
            raise ModelError("strain hardening acts on the cable's elastic path, which the TESTBED form's unit does "
                             "not have (tau_in drives the environment through the friction state)")
        if not ch > 0.0:
            raise ModelError(f"strain hardening c_node_1_rad2 must be >= 0 (a stiffening cable), got {ch}")
        assert sig.q_in_rad is not None
        if form in INPUT_PREDICTED:
            K1, A1, K2, A2 = float(K), sig.q_in_rad, 0.0, np.empty(0)
        else:
            K1, A1, K2, A2 = float(Kh), sig.q_in_rad, float(Kh), rho * sig.q_out_rad
        done = simulate_unit_hardening(sig.t_s, np.ascontiguousarray(a, dtype=np.float64), starts,
                                       np.asarray(x0, np.float64), c0_r, kx_r, float(kp), float(tfc), float(zs),
                                       float(eta), float(bv), x, v, fr, cap, float(mods.c2_Nms2_rad2),
                                       float(dahl_exp), ch, K1, np.ascontiguousarray(A1, dtype=np.float64), K2,
                                       np.ascontiguousarray(A2, dtype=np.float64))
    if done != n:
        raise ModelError(f"dynamic baseline: the simulation failed at sample {done} (t = {sig.t_s[done]:.4f} s): "
                         "time not increasing or no damping/stiffness in the unit")
    if form in INPUT_PREDICTED:
        e = sig.q_in_rad - x
        out: tuple[np.ndarray, np.ndarray | None] = (K * e * (1.0 + ch * e * e) + d_in * (dq_in - v) + c_in
                                                     if ch != 0.0 else K * e + d_in * (dq_in - v) + c_in, None)
    elif form == DrivingForm.TESTBED:
        out = (kout * x + bout * v + c_out, None)
    else:
        assert sig.q_in_rad is not None
        if ch == 0.0:
            out = (rho * Kh * (x - rho * sig.q_out_rad) + c_out, Kh * (sig.q_in_rad - x) + c_in)
        else:
            e1, e2 = sig.q_in_rad - x, x - rho * sig.q_out_rad
            out = (rho * Kh * e2 * (1.0 + ch * e2 * e2) + c_out, Kh * e1 * (1.0 + ch * e1 * e1) + c_in)
    if mods.lag_s != 0.0:
        out = (shift_within_runs(out[0], sig, mods.lag_s),
               None if out[1] is None else shift_within_runs(out[1], sig, mods.lag_s))
    return out


def input_velocity(sig: Signals) -> np.ndarray:
    """dq_in [rad/s] (Savitzky-Golay derivative of q_in inside each run, as for q_out).

    :raises ModelError: without q_in.
    """
    if sig.q_in_rad is None:
        raise ModelError("no input angle q_in in the runs")
    out = np.zeros(len(sig))
    for a, b in sig.segments():
        if b - a > 1:
            out[a:b] = derivative(sig.q_in_rad[a:b], float(np.median(np.diff(sig.t_s[a:b]))), VELOCITY_WINDOW_S)
    return out


def _velocity_scale(sig: Signals, form: DrivingForm) -> float:
    if form in INPUT_PREDICTED and sig.q_in_rad is not None:
        dq = input_velocity(sig)
    else:
        dq = sig.dq_out_rad_s
    v95 = float(np.percentile(np.abs(dq), 95)) if dq.size else 0.0
    if not v95 > 0.0:
        raise ModelError("the runs carry no motion (velocity is zero); nothing to identify")
    return v95


def _initial(sig: Signals, spec: FormSpec, v95: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[bool]]:
    """(start, lower bounds, upper bounds, fixed-by-declaration flags) of the parameter vector."""
    form = spec.form
    rho = sig.ratio_q
    tin, tout = sig.tau_in_Nm, sig.tau_out_Nm
    moving = np.abs(sig.dq_out_rad_s) > 0.2 * v95 if form not in INPUT_PREDICTED else slice(None)
    fixed = [False] * len(PARAM_NAMES[form])
    if form in INPUT_PREDICTED:
        assert sig.q_in_rad is not None
        B = np.column_stack([tout, np.ones(len(sig))])
        g0, c0 = np.linalg.lstsq(B, tin, rcond=None)[0]
        g0 = max(float(g0), 1e-3)
        f = tin - g0 * tout - c0
        span_q = float(np.ptp(sig.q_in_rad)) or 1.0
        K0 = 20.0 * float(np.ptp(tin)) / span_q
        tfc0 = max(float(np.percentile(np.abs(f), 50)), 1e-6)
        kp0 = tfc0 / (PRESLIDE_FRACTION * span_q)
        x0 = [K0, g0, tfc0, kp0, ZETA_S0, 0.2 * v95, 1e-3 * tfc0 / v95, float(c0), DAHL_EXP0, 0.0]
        if form == DrivingForm.LINK:
            # the output load cells measure the torque on the output pulley: g = r_in / r_out
            # (the inverse angle ratio) is geometry, not fitted (a free g takes up effects)
            x0[1], fixed[1] = 1.0 / sig.ratio_q, True
            # with g fixed: the offset at the middle of the friction band tau_in - g tau_out,
            # the capacity at its half width
            fb = tin - x0[1] * tout
            lo5, hi95 = (float(v) for v in np.percentile(fb, [5, 95]))
            x0[7], x0[2] = 0.5 * (lo5 + hi95), max(0.5 * (hi95 - lo5), 1e-6)
            # the input half of the cable (K_h = 2 K_c) from the link's elastic path: the
            # stroke-based start above is far softer on a link and the fit stalls there
            kc = float(fit_elastic(sig).get("elastic", {}).get("K_c_Nm_rad", 0.0))
            if kc > 0.0:
                x0[0] = 2.0 * kc
            x0[9] = D_IN_TAU0_S * x0[0]
        lo = [1e-6 * K0, 1e-9, 0.0, 1e-6 * kp0, 1.0, 1e-4 * v95, 0.0, -np.inf, DAHL_EXP_MIN, 0.0]
        hi = [np.inf, np.inf, np.inf, np.inf, 5.0, 100.0 * v95, np.inf, np.inf, DAHL_EXP_MAX, np.inf]
        if form == DrivingForm.OUTPUT_HELD:
            x0[8], fixed[8], fixed[9] = 1.0, True, True
    elif form == DrivingForm.TESTBED:
        if sig.environment is not None:
            k0, b0 = float(sig.environment[0, 0]), float(sig.environment[0, 1])
            fixed[0] = fixed[1] = True
        else:
            Bq = np.column_stack([sig.q_out_rad, sig.dq_out_rad_s, np.ones(len(sig))])
            k0, b0, _ = np.linalg.lstsq(Bq, tout, rcond=None)[0]
            k0, b0 = max(float(k0), 1e-3), max(float(b0), 1e-3)
        f = rho * tin - tout
        tfc0 = max(float(np.percentile(np.abs(f[moving]), 50)) if np.any(moving) else 0.0, 1e-6)
        kp0 = tfc0 / (PRESLIDE_FRACTION * max(float(np.ptp(sig.q_out_rad)), 1e-9))
        x0 = [k0, b0, tfc0, kp0, ZETA_S0, 0.2 * v95, 1e-3 * tfc0 / v95, 0.0]
        lo = [1e-9, 1e-9, 0.0, 1e-6 * kp0, 1.0, 1e-4 * v95, 0.0, -np.inf]
        hi = [np.inf, np.inf, np.inf, np.inf, 5.0, 100.0 * v95, np.inf, np.inf]
    else:
        el = fit_elastic(sig).get("elastic", {})
        K0 = float(el.get("K_c_Nm_rad", 0.0))
        if not K0 > 0.0:
            K0 = float(np.ptp(tout)) / max(float(np.ptp(sig.deflection_rad)), 1e-9)   # type: ignore[arg-type]
        f = tin - tout / rho
        tfc0 = max(float(np.percentile(np.abs(f[moving]), 50)) if np.any(moving) else 0.0, 1e-6)
        kp0 = tfc0 / (PRESLIDE_FRACTION * max(float(np.ptp(sig.q_out_rad)), 1e-9))
        x0 = [K0, tfc0, kp0, ZETA_S0, 0.2 * v95, 1e-3 * tfc0 / v95, 0.0, 0.0]
        lo = [1e-6 * K0, 0.0, 1e-6 * kp0, 1.0, 1e-4 * v95, 0.0, -np.inf, -np.inf]
        hi = [np.inf, np.inf, np.inf, 5.0, 100.0 * v95, np.inf, np.inf, np.inf]
    return np.array(x0, float), np.array(lo, float), np.array(hi, float), fixed


def _target(sig: Signals, spec: FormSpec) -> np.ndarray:
    return sig.tau_in_Nm if spec.target == "tau_in" else sig.tau_out_Nm


def fit_dynamic(sig: Signals, spec: FormSpec | None = None, max_nfev: int = MAX_NFEV,
                warm_start_samples: int | None = None) -> DynamicFit:
    """Fit the dynamic baseline to the training runs ``sig`` (every sample).

    Up to ``warm_start_samples`` (default ``windows.WARM_START_SAMPLES``) samples: bounded
    least squares (scipy, trust region reflective) from the data-derived start. Longer runs: the same fit on contiguous windows
    (:mod:`capstan.models.closure.windows`), then ``FINAL_ITERS`` bounded Levenberg-Marquardt
    steps on every sample (:mod:`capstan.models.common.projected_lm`); the parameters and
    the training RMSE are those on every sample, the covariance is the sandwich of the
    every-sample Jacobian of the last step (at its start: the step from a warm start is small).

    :raises ModelError: if the runs carry no motion, lack the channels of the form, or
        the simulation fails.
    """
    spec = spec or choose_form(sig)
    form = spec.form
    v95 = _velocity_scale(sig, form)
    p0, lo, hi, fixed = _initial(sig, spec, v95)
    free = np.array([not f for f in fixed])
    declared = bool(form == DrivingForm.TESTBED and fixed[0])
    y = _target(sig, spec)
    names = PARAM_NAMES[form]

    def full(pf: np.ndarray) -> np.ndarray:
        p = p0.copy()
        p[free] = pf
        return p

    def resid(pf: np.ndarray) -> np.ndarray:
        pred, other = _predict(form, full(pf), sig, declared)
        if other is None:
            return pred - y
        return np.concatenate([pred - y, other - sig.tau_in_Nm])

    x0 = np.clip(p0[free], lo[free], hi[free])
    scale = np.maximum(np.abs(x0), 1e-3 * v95)
    if len(sig) > (windows.WARM_START_SAMPLES if warm_start_samples is None else warm_start_samples):
        # long runs: solved on contiguous windows first, finished on every sample
        warm = fit_dynamic(sig.take(windows.window_index(sig)), spec, max_nfev, warm_start_samples=len(sig))
        xw = np.clip(param_vector(form, warm.params)[free], lo[free], hi[free])
        lm = projected_lm(resid, xw, lo[free], hi[free], scale, FINAL_ITERS, DIFF_STEP, want_jac=True,
                          final_jac=False)
        assert lm.jac is not None
        xf, r, J, nfev = lm.x, lm.r, lm.jac, warm.nfev + lm.nfev
    else:
        res = least_squares(resid, x0, bounds=(lo[free], hi[free]), x_scale=scale, diff_step=DIFF_STEP,
                            max_nfev=max_nfev, method="trf")
        xf, r, J, nfev = res.x, res.fun, res.jac, int(res.nfev)
    p = full(xf)
    cov = sandwich_cov(J, r)
    se_free = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    params = {nm: float(v) for nm, v in zip(names, p)}
    stderr = {nm: 0.0 for nm in names}
    for nm, s in zip([nm for nm, f in zip(names, free) if f], se_free):
        stderr[nm] = float(s)
    fit = DynamicFit(spec, params, stderr, n_samples=len(sig), nfev=nfev, declared_env=declared)
    fit.pred_train_Nm = r[:len(sig)] + y          # (the residual's first block is the target's)
    fit.rmse_Nm = float(np.sqrt(np.mean(r[:len(sig)] ** 2)))
    for i, nm in enumerate(names):
        if not free[i]:
            continue
        tol = 1e-6 * max(abs(p[i]), 1e-9) + 1e-12
        if (np.isfinite(lo[i]) and p[i] - lo[i] <= max(tol, 1e-4 * abs(lo[i]))) or \
                (np.isfinite(hi[i]) and hi[i] - p[i] <= max(tol, 1e-4 * abs(hi[i]))):
            fit.at_bound.append(nm)
    fit.implausible, weak = split_by_uncertainty(plausibility(params, y, v95), params, stderr, y, v95)
    fit.undetermined = [nm for i, nm in enumerate(names) if free[i] and stderr[nm] > abs(p[i])]
    if params["zeta_s"] - 1.0 <= 1e-3 and "eta_s_rad_s" not in fit.undetermined:
        fit.undetermined.append("eta_s_rad_s")     # no stiction peak: its width means nothing
    fit.warnings = power_warnings(sig, form) + weak
    return fit


def power_warnings(sig: Signals, form: DrivingForm) -> list[str]:
    """A warning when the mean input power ``tau_in dq_in`` is negative (the drive cannot take
    energy out of a passive transmission: a sign convention of the import is wrong)."""
    if sig.q_in_rad is None:
        return []
    p = float(np.mean(sig.tau_in_Nm * input_velocity(sig)))
    if p < 0.0:
        return [f"mean input power tau_in * dq_in is negative ({p:.3g} W): the signs of tau_in and q_in "
                "disagree (fix the sign of one of them in the import description)"]
    return []
