"""The catalogue of physical effects the reduced model lacks.

Each entry states a mechanism, a parametric form and the signals it depends on (the
``depends_on`` words of the closure). Forms are linear in their coefficients once a
few *shape* parameters (time constants, lags) are fixed; the closure searches the
shape grid on the training data and solves the coefficients by least squares together
with the baseline's parameters (its nonlinear shape refitted too, models.baseline_shape).
``sensor_latency`` has no basis: it names the late channel and its lag, and the closure
re-evaluates the whole model on the realigned signals (models.closure_model).

Sign convention: an effect is an extra transmission loss torque ``tau_e`` [Nm] acting
like friction, ``tau_out = baseline - tau_e``; the feedforward *adds* ``tau_e`` to the
torque reference. ``s(dq)`` is the baseline's normalised friction shape (eq 21 divided
by tau_fc, odd in velocity, ~ +-1 when sliding). ``*_ref`` values are training means.

======================  ============  =====================================================
effect                  depends_on    tau_e (coefficients in capitals)
======================  ============  =====================================================
dwell_stiction          dwell         A s(dq) (1 - exp(-rest/tau_age)) exp(-slide/s0)
speed_viscous           velocity      C2 dq |dq| + C3 dq^3
position_friction       position      s(dq) (A1 (q - q_ref) + A2 (q - q_ref)^2)
pretension_relaxation   time          D s(dq) (1 - exp(-t/tau_r))
sensor_latency          latency       tau_out channel (or dq_out channel) delayed by lag
nonlinear_stiffness     deflection    elastic path: tau_in + tau_out = 2(K_c x + K3 x^3 + K2 x|x|)
load_friction           load          CL s(dq) |tau_in|
temperature_drift       <temp chan>   s(dq) CT (T - T_ref) + CO (T - T_ref)
tension_friction        tension       CT s(dq) (T_lc - T_ref)
output_inertia          acceleration  J ddq_out
======================  ============  =====================================================

Mechanisms: stiction grows with rest time (junction ageing) and is lost after a short
slide; lubricant/hydrodynamic drag rises faster than linearly at speed; the routing
bends with the joint so the accumulated angle theta (and mu theta T0_eq) depends on q;
pretension relaxes (cable creep) so tau_fc = mu theta T0_eq r falls over the session;
sensors report late; the cable stiffens with strain; the capstan law scales friction
with the transmitted tension; mu changes with temperature; friction scales with the
measured pretension; the pulley/link inertia the massless model ignores.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Callable

import numpy as np

from capstan.models.closure.identification import BaselineFit
from capstan.models.closure.signals import Signals


class Target(IntEnum):
    """Which prediction an effect corrects."""

    TAU_OUT = 0      # output torque from input torque and velocity (friction path)
    ELASTIC = 1      # tau_in + tau_out from the deflection (elastic path)


@dataclass
class FeatureContext:
    """Everything a feature needs besides the signals: the baseline and training references."""

    baseline: BaselineFit
    q_ref_rad: float = 0.0
    refs: dict[str, float] = field(default_factory=dict)
    dt_s: float = 1e-3

    @staticmethod
    def from_train(sig: Signals, baseline: BaselineFit) -> "FeatureContext":
        """References (means) from the training signals."""
        refs = {name: float(np.mean(x)) for name, x in sig.extras.items()}
        if sig.tension_N is not None:
            refs["tension"] = float(np.mean(sig.tension_N))
        dt = float(np.median(np.diff(sig.t_s))) if len(sig) > 1 else 1e-3
        return FeatureContext(baseline, float(np.mean(sig.q_out_rad)), refs, dt if dt > 0 else 1e-3)


Shape = dict[str, float | str]
FeatureFn = Callable[[Signals, FeatureContext, Shape], np.ndarray]


@dataclass(frozen=True)
class EffectSpec:
    """One catalogue entry (see module table).

    ``features(sig, ctx, shape)`` returns the (n x k) basis whose coefficients are
    ``coef_names``: tau_e = basis @ coef (TAU_OUT) or the elastic-path addition.
    """

    name: str
    depends_on: tuple[str, ...]
    mechanism: str
    form: str
    coef_names: tuple[str, ...]
    grid: tuple[Shape, ...]
    features: FeatureFn
    target: Target = Target.TAU_OUT
    needs: tuple[str, ...] = ()
    loss_sign: float = -1.0     # residual contribution = loss_sign * basis @ coef
    realigns: bool = False      # True: the shape names a late channel and its lag; the baseline is
                                # re-evaluated on the realigned channel and refitted (no basis)
    full_rate: bool = False     # True: compute on full-rate signals (time shifts), then decimate

    def applicable(self, sig: Signals) -> bool:
        """True if the signals this effect needs are present."""
        return all(sig.signal(n) is not None for n in self.needs)


def _grid(**axes: list) -> tuple[Shape, ...]:
    keys = list(axes)
    return tuple(dict(zip(keys, combo)) for combo in itertools.product(*[axes[k] for k in keys]))


def _shape(sig: Signals, ctx: FeatureContext) -> np.ndarray:
    return ctx.baseline.friction_shape(sig.dq_out_rad_s)


def _f_dwell(sig: Signals, ctx: FeatureContext, sh: Shape) -> np.ndarray:
    g = (1.0 - np.exp(-sig.rest_s / float(sh["tau_age_s"]))) * np.exp(-sig.slide_rad / float(sh["s0_rad"]))
    return (_shape(sig, ctx) * g)[:, None]


def _f_speed(sig: Signals, ctx: FeatureContext, sh: Shape) -> np.ndarray:
    v = sig.dq_out_rad_s
    return np.column_stack([v * np.abs(v), v ** 3])


def _f_position(sig: Signals, ctx: FeatureContext, sh: Shape) -> np.ndarray:
    dq = sig.q_out_rad - ctx.q_ref_rad
    s = _shape(sig, ctx)
    return np.column_stack([s * dq, s * dq * dq])


def _f_relax(sig: Signals, ctx: FeatureContext, sh: Shape) -> np.ndarray:
    return (_shape(sig, ctx) * (1.0 - np.exp(-sig.t_s / float(sh["tau_r_s"]))))[:, None]


def shift_within_runs(x: np.ndarray, sig: Signals, lag_s: float) -> np.ndarray:
    """``x`` delayed by ``lag_s`` (advanced if negative), rounded to whole samples of the
    run's median period, inside each run with the ends held. Whole samples only: an
    interpolating shift would average neighbouring noise and look like an improvement."""
    out = np.empty_like(x)
    for a, b in sig.segments():
        seg = x[a:b]
        dt = float(np.median(np.diff(sig.t_s[a:b]))) if b - a > 1 else 1.0
        lag = int(round(lag_s / dt)) if dt > 0 else 0
        if lag == 0 or b - a <= abs(lag):
            out[a:b] = seg
        elif lag > 0:
            out[a:a + lag] = seg[0]
            out[a + lag:b] = seg[:-lag]
        else:
            out[a:b + lag] = seg[-lag:]
            out[b + lag:b] = seg[-1]
    return out


def _f_latency(sig: Signals, ctx: FeatureContext, sh: Shape) -> np.ndarray:
    """No basis of its own: the closure re-evaluates the whole baseline on the realigned
    channel (:func:`capstan.models.closure.augmented.realigned_signals`) and refits it."""
    return np.zeros((len(sig), 0))


def _f_stiff(sig: Signals, ctx: FeatureContext, sh: Shape) -> np.ndarray:
    x = sig.deflection_rad
    assert x is not None
    return np.column_stack([2.0 * x ** 3, 2.0 * x * np.abs(x)])


def _f_load(sig: Signals, ctx: FeatureContext, sh: Shape) -> np.ndarray:
    return (_shape(sig, ctx) * np.abs(sig.tau_in_Nm))[:, None]


def _f_channel(sig: Signals, ctx: FeatureContext, sh: Shape) -> np.ndarray:
    name = str(sh["channel"])
    x = sig.signal(name)
    assert x is not None
    d = x - ctx.refs.get(name, 0.0)
    return np.column_stack([_shape(sig, ctx) * d, d])


def _f_tension(sig: Signals, ctx: FeatureContext, sh: Shape) -> np.ndarray:
    assert sig.tension_N is not None
    return (_shape(sig, ctx) * (sig.tension_N - ctx.refs.get("tension", 0.0)))[:, None]


def _f_inertia(sig: Signals, ctx: FeatureContext, sh: Shape) -> np.ndarray:
    return sig.ddq_out_rad_s2[:, None]


_LAGS_MS = (1, 2, 3, 5, 8, 12, 18, 25, 35, 50, 70, 100)

CATALOGUE: tuple[EffectSpec, ...] = (
    EffectSpec("dwell_stiction", ("dwell",), "stiction grows with rest time, lost after a short slide",
               "A s(dq) (1-exp(-rest/tau_age)) exp(-slide/s0)", ("amp_Nm",),
               _grid(tau_age_s=[0.3, 1.0, 3.0, 10.0], s0_rad=[0.01, 0.03, 0.1, 0.3]), _f_dwell),
    EffectSpec("speed_viscous", ("velocity",), "distributed viscous drag rising faster than linearly with speed",
               "C2 dq|dq| + C3 dq^3", ("c2_Nms2_rad2", "c3_Nms3_rad3"), ({},), _f_speed),
    EffectSpec("position_friction", ("position",), "routing bends with the joint: theta, hence tau_fc, depends on q",
               "s(dq) (A1 (q-q_ref) + A2 (q-q_ref)^2)", ("a1_Nm_rad", "a2_Nm_rad2"), ({},), _f_position),
    EffectSpec("pretension_relaxation", ("time",), "cable creep relaxes the pretension, tau_fc falls over the session",
               "D s(dq) (1-exp(-t/tau_r))", ("d_Nm",),
               _grid(tau_r_s=[3.0, 10.0, 30.0, 100.0, 300.0, 1000.0, 1e4]), _f_relax),
    EffectSpec("sensor_latency", ("latency",), "a measured channel arrives late relative to the others",
               "tau_out(t) measured as tau_out(t - lag), or dq_out late by lag", (),
               tuple({"channel": c, "lag_s": s * m / 1000.0} for c in ("tau_out", "dq_out")
                     for m in _LAGS_MS for s in (1, -1)), _f_latency, loss_sign=1.0, realigns=True,
               full_rate=True),
    EffectSpec("nonlinear_stiffness", ("deflection",), "the cable stiffens with strain (hardening/softening)",
               "tau_in + tau_out = 2 (K_c x + K3 x^3 + K2 x|x|)", ("K3_Nm_rad3", "K2_Nm_rad2"), ({},),
               _f_stiff, Target.ELASTIC, ("deflection",), loss_sign=1.0),
    EffectSpec("load_friction", ("load",), "capstan law: friction scales with the transmitted tension",
               "CL s(dq) |tau_in|", ("c_load",), ({},), _f_load),
    EffectSpec("tension_friction", ("tension",), "friction scales with the measured pretension (eq 19)",
               "CT s(dq) (T_lc - T_ref)", ("c_Nm_N",), ({},), _f_tension, needs=("tension",)),
    EffectSpec("output_inertia", ("acceleration",), "pulley/link inertia ignored by the massless model",
               "J ddq_out", ("J_kg_m2",), ({},), _f_inertia),
)


def temperature_effects(sig: Signals) -> list[EffectSpec]:
    """One ``temperature_drift`` entry per extra channel whose name says temperature."""
    out = []
    for name in sig.extras:
        if "temp" in name.lower():
            out.append(EffectSpec("temperature_drift", (name,), "mu and sensor offsets drift with temperature",
                                  "s(dq) CT (T-T_ref) + CO (T-T_ref)", ("ct_Nm_K", "co_Nm_K"),
                                  ({"channel": name},), _f_channel, needs=(name,)))
    return out


def catalogue_for(sig: Signals) -> list[EffectSpec]:
    """The catalogue entries applicable to ``sig`` (temperature entries per channel)."""
    return [e for e in CATALOGUE if e.applicable(sig)] + temperature_effects(sig)
