"""Baseline transmission models of the paper's Fig. 11 and the common predictor interface.

Three predictors map an input-torque history to the testbed output torque
(``tau_out = k_out q_out + b_out dq_out``, eq 22) and can be swapped by identification and
the paper reproduction through :func:`predict_tau_out` / :func:`fit_parameters`:

* :class:`capstan.models.transmission.reduced.ReducedModel` - this work (eq 20/21, smooth virtual state);
* :func:`wu_model` - Wu-type analytical mapping (constant curvature, uniform pretension);
* :func:`single_sided_model` - the authors' previous single-sided-pretension model.

**Wu-type form implemented.** Wu et al. (IEEE TIE 62(3), 2015, "Transmission model and
compensation control of double-tendon-sheath actuation system") model a pretensioned
double tendon-sheath with constant curvature and uniform pretension T0. The full text was
not available here; what is implemented is the closed form that model class reduces to,
derived from the same assumptions (capstan law along the sheath, constant curvature, uniform
pretension T0, rigid pulleys, linear elastic cables whose total elongation is conserved):
in forward sliding the pulled cable decays as ``T_p e^{-mu s kappa}``, the released one
grows as ``T_p e^{+mu s kappa}``; length compatibility ``int T_1 + int T_2 = 2 T0 L`` then
gives exactly ::

    tau_out = rho tau_in -/+ tau_w,     tau_w = 2 mu theta T0 r_out,    rho = r_out / r_in

on the forward/backward sliding branches (the same slope 1 and, for uniform pretension
``T0_eq = 2 T0``, the same offset as eq 19 - the paper's remark that Wu/Jung-type mappings
are a special case). Between the branches the transmission sticks (threshold/backlash
gating): the output does not move, so a spring-dominated output holds its torque (play
operator) while a damped output relaxes. The least-squares parameters are the lumped
``gain`` (rho) and ``threshold_Nm`` (tau_w, i.e. the ``mu theta T0`` product), as in the
paper's comparison.

**Single-sided variant (our reading of the previous model).** The pretension field is
propagated from the input fixture only, ``T(s) = T_a exp(-mu int_0^s kappa)``, and its
average replaces T0 in the same gated law: ``tau_w = 2 mu theta T_avg r_out``. The average is
the arc-length mean ``(1/L) int_0^L T ds`` (depends on where the bends are; default) or, with
:attr:`PretensionAverage.BENDING`, the bending-weighted mean
``int T kappa ds / theta = T_a (1 - e^{-mu theta}) / (mu theta)``, which preserves the total
Coulomb friction of the field. Both equal the uniform-curvature value on a uniform routing.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Protocol, Sequence

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from capstan.models.common.errors import ModelError
from capstan.models.transmission.reduced import ReducedModel, _check_series
from capstan.models.transmission.routing import Routing


class BaselineKind(IntEnum):
    """Which baseline a :class:`GatedTransmission` represents (label only; same dynamics)."""

    WU = 1
    SINGLE_SIDED = 2


class PretensionAverage(IntEnum):
    """How the single-sided pretension field is averaged."""

    ARC_LENGTH = 1
    BENDING = 2


class TorquePredictor(Protocol):
    """Anything that predicts the testbed output torque from an input-torque series."""

    def predict_tau_out(self, t_s: ArrayLike, tau_in_Nm: ArrayLike) -> np.ndarray:
        """(n,) predicted output torque [Nm] for (n,) times [s] and input torques [Nm]."""
        ...


@njit(cache=True)
def gated_step(q_rad: float, tau_in_Nm: float, dt_s: float, gain: float, threshold_Nm: float,
               k_out_Nm_rad: float, b_out_Nms_rad: float) -> tuple[float, float]:
    """One backward-Euler step of the threshold-gated transmission with the testbed output.

    The output moves forward when ``gain tau_in - threshold > k_out q + b_out dq`` can hold
    with ``dq > 0``, backward when ``gain tau_in + threshold < k_out q + b_out dq`` with
    ``dq < 0``, and sticks (``dq = 0``) otherwise. Needs ``k_out + b_out / dt > 0``.

    :returns: ``(q_new, dq_new)`` [rad, rad/s]; ``tau_out = k_out q_new + b_out dq_new``.
    """
    c = b_out_Nms_rad / dt_s + k_out_Nm_rad
    drive = gain * tau_in_Nm
    base = b_out_Nms_rad * q_rad / dt_s
    q_fwd = (base + drive - threshold_Nm) / c
    if q_fwd > q_rad:
        return q_fwd, (q_fwd - q_rad) / dt_s
    q_bwd = (base + drive + threshold_Nm) / c
    if q_bwd < q_rad:
        return q_bwd, (q_bwd - q_rad) / dt_s
    return q_rad, 0.0


@njit(cache=True)
def _simulate_gated(t_s, tau_in_Nm, q0, gain, threshold, k_out, b_out, q_out, dq_out, tau_out):
    q = q0
    q_out[0] = q
    dq_out[0] = 0.0
    tau_out[0] = k_out * q
    for i in range(1, t_s.shape[0]):
        q, v = gated_step(q, tau_in_Nm[i], t_s[i] - t_s[i - 1], gain, threshold, k_out, b_out)
        q_out[i] = q
        dq_out[i] = v
        tau_out[i] = k_out * q + b_out * v


@dataclass(frozen=True)
class GatedTransmission:
    """Threshold-gated analytical transmission (Wu-type and single-sided baselines).

    :ivar gain: slope of the sliding branches, rho = r_out / r_in [-].
    :ivar threshold_Nm: half-width tau_w of the stick band [Nm].
    :ivar k_out_Nm_rad: testbed output stiffness [Nm/rad].
    :ivar b_out_Nms_rad: testbed output damping [Nm s/rad].
    :ivar kind: which baseline this is (label).
    """

    gain: float
    threshold_Nm: float
    k_out_Nm_rad: float = 20.0
    b_out_Nms_rad: float = 2.0
    kind: BaselineKind = BaselineKind.WU

    def __post_init__(self) -> None:
        if not (math.isfinite(self.gain) and math.isfinite(self.threshold_Nm) and self.threshold_Nm >= 0.0):
            raise ModelError(f"need finite gain and threshold_Nm >= 0, got {self.gain}, {self.threshold_Nm}")
        if not (self.k_out_Nm_rad >= 0.0 and self.b_out_Nms_rad >= 0.0
                and self.k_out_Nm_rad + self.b_out_Nms_rad > 0.0):
            raise ModelError("testbed output needs k_out_Nm_rad >= 0, b_out_Nms_rad >= 0, not both 0, got "
                             f"{self.k_out_Nm_rad}, {self.b_out_Nms_rad}")

    def simulate(self, t_s: ArrayLike, tau_in_Nm: ArrayLike,
                 q0_rad: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Simulate from rest; returns ``(q_out_rad, dq_out_rad_s, tau_out_Nm)``, each (n,).

        :raises ModelError: on mismatched or non-monotonic series.
        """
        t = np.ascontiguousarray(t_s, dtype=float)
        u = np.ascontiguousarray(tau_in_Nm, dtype=float)
        _check_series(t, u)
        q, dq, out = np.zeros(t.size), np.zeros(t.size), np.zeros(t.size)
        _simulate_gated(t, u, float(q0_rad), self.gain, self.threshold_Nm, self.k_out_Nm_rad,
                        self.b_out_Nms_rad, q, dq, out)
        return q, dq, out

    def predict_tau_out(self, t_s: ArrayLike, tau_in_Nm: ArrayLike) -> np.ndarray:
        """Predicted testbed output torque [Nm] (common predictor interface)."""
        return self.simulate(t_s, tau_in_Nm)[2]


def wu_model(mu_theta: float, T0_N: float, r_out_m: float, r_in_m: float | None = None,
             k_out_Nm_rad: float = 20.0, b_out_Nms_rad: float = 2.0) -> GatedTransmission:
    """Wu-type mapping: constant curvature, uniform pretension ``T0``; ``tau_w = 2 mu theta T0 r_out``.

    :param mu_theta: product of friction coefficient and total bending [-] (lumped, identifiable).
    :param T0_N: uniform pretension of each cable [N].
    :raises ModelError: on negative inputs.
    """
    if not (mu_theta >= 0.0 and T0_N >= 0.0 and r_out_m > 0.0):
        raise ModelError(f"need mu_theta >= 0, T0_N >= 0, r_out_m > 0, got {mu_theta}, {T0_N}, {r_out_m}")
    rho = 1.0 if r_in_m is None else float(r_out_m) / float(r_in_m)
    return GatedTransmission(rho, 2.0 * mu_theta * T0_N * r_out_m, k_out_Nm_rad, b_out_Nms_rad, BaselineKind.WU)


def single_sided_pretension_N(routing: Routing, mu: float, T_a_N: float,
                              average: PretensionAverage = PretensionAverage.ARC_LENGTH) -> float:
    """Average of the single-sided field ``T_a exp(-mu int_0^s kappa)`` [N] (see module doc).

    :raises ModelError: on negative mu or non-positive ``T_a_N``.
    """
    if not (mu >= 0.0 and T_a_N > 0.0):
        raise ModelError(f"need mu >= 0 and T_a_N > 0, got {mu}, {T_a_N}")
    x = mu * routing.theta_total_rad
    if average == PretensionAverage.BENDING:
        return float(T_a_N * (-math.expm1(-x) / x if x > 0.0 else 1.0))
    s_knots, _ = routing.curvature_profile()
    # exact knots plus a fine grid: the integrand is smooth between knots
    s = np.union1d(s_knots, np.linspace(0.0, routing.length_m, 2001))
    f = np.exp(-mu * routing.cumulative_bending_rad(s))
    return float(T_a_N * np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(s)) / routing.length_m)


def single_sided_model(routing: Routing, mu: float, T_a_N: float, r_out_m: float, r_in_m: float | None = None,
                       k_out_Nm_rad: float = 20.0, b_out_Nms_rad: float = 2.0,
                       average: PretensionAverage = PretensionAverage.ARC_LENGTH) -> GatedTransmission:
    """Single-sided-pretension model: ``tau_w = 2 mu theta T_avg r_out`` with the averaged one-sided field.

    :raises ModelError: on invalid inputs.
    """
    t_avg = single_sided_pretension_N(routing, mu, T_a_N, average)
    rho = 1.0 if r_in_m is None else float(r_out_m) / float(r_in_m)
    return GatedTransmission(rho, 2.0 * mu * routing.theta_total_rad * t_avg * r_out_m,
                             k_out_Nm_rad, b_out_Nms_rad, BaselineKind.SINGLE_SIDED)


def predict_tau_out(t_s: ArrayLike, tau_in_Nm: ArrayLike, params: TorquePredictor) -> np.ndarray:
    """Common entry point: predicted output torque [Nm] of any predictor (reduced, Wu, single-sided).

    :raises ModelError: on invalid series or parameters.
    """
    return params.predict_tau_out(t_s, tau_in_Nm)


def rmse_Nm(a_Nm: ArrayLike, b_Nm: ArrayLike) -> float:
    """Root-mean-square difference [Nm] of two equally long series."""
    a = np.asarray(a_Nm, dtype=float)
    b = np.asarray(b_Nm, dtype=float)
    return float(np.sqrt(np.mean((a - b) ** 2)))


def _get(obj: Any, name: str) -> float:
    for part in name.split("."):
        obj = getattr(obj, part)
    return float(obj)


def _set(obj: Any, name: str, value: float) -> Any:
    head, _, rest = name.partition(".")
    if rest:
        return dataclasses.replace(obj, **{head: _set(getattr(obj, head), rest, value)})
    return dataclasses.replace(obj, **{head: value})


def parameter_values(model: Any, names: Sequence[str]) -> np.ndarray:
    """(n,) current values of the named (dotted for nested) float fields of ``model``.

    :raises ModelError: on an unknown name.
    """
    try:
        return np.array([_get(model, n) for n in names], dtype=float)
    except AttributeError as exc:
        raise ModelError(f"unknown parameter name: {exc}") from exc


def with_parameters(model: Any, names: Sequence[str], values: ArrayLike) -> Any:
    """A copy of the frozen dataclass ``model`` with the named fields set to ``values``.

    :raises ModelError: on an unknown name or a value the model refuses.
    """
    m = model
    try:
        for n, v in zip(names, np.asarray(values, dtype=float)):
            m = _set(m, n, float(v))
    except TypeError as exc:
        raise ModelError(f"unknown parameter name in {list(names)}: {exc}") from exc
    return m


def fit_parameters(model: TorquePredictor, names: Sequence[str], t_s: ArrayLike, tau_in_Nm: ArrayLike,
                   tau_out_meas_Nm: ArrayLike, lower: Sequence[float] | None = None,
                   upper: Sequence[float] | None = None) -> tuple[Any, float]:
    """Least-squares fit of the named (dotted for nested, e.g. ``"stribeck.zeta_s"``) float fields.

    Minimises the output-torque residual with ``scipy.optimize.least_squares`` (trust region,
    finite differences) starting from ``model``'s values.

    :param model: a frozen dataclass predictor (:class:`GatedTransmission`, :class:`ReducedModel`).
    :returns: ``(fitted model, RMSE [Nm])``.
    :raises ModelError: on unknown names, invalid series or parameter values the model refuses.
    """
    from scipy.optimize import least_squares

    t = np.asarray(t_s, dtype=float)
    u = np.asarray(tau_in_Nm, dtype=float)
    y = np.asarray(tau_out_meas_Nm, dtype=float)
    if y.shape != u.shape:
        raise ModelError(f"measured tau_out shape {y.shape} differs from tau_in shape {u.shape}")
    x0 = parameter_values(model, names)
    lo = np.full(x0.size, -np.inf) if lower is None else np.asarray(lower, dtype=float)
    hi = np.full(x0.size, np.inf) if upper is None else np.asarray(upper, dtype=float)

    def build(x: np.ndarray) -> Any:
        return with_parameters(model, names, x)

    def resid(x: np.ndarray) -> np.ndarray:
        try:
            return build(x).predict_tau_out(t, u) - y
        except ModelError:
            return np.full(y.size, 1e6)

    sol = least_squares(resid, np.clip(x0, lo, hi), bounds=(lo, hi), x_scale="jac", diff_step=1e-4)
    fitted = build(sol.x)
    return fitted, rmse_Nm(fitted.predict_tau_out(t, u), y)


__all__ = [
    "BaselineKind", "GatedTransmission", "PretensionAverage", "ReducedModel", "TorquePredictor", "fit_parameters",
    "gated_step", "parameter_values", "predict_tau_out", "rmse_Nm", "single_sided_model", "single_sided_pretension_N", "with_parameters", "wu_model",
]
