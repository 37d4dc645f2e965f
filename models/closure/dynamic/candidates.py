"""The in-model effect candidates: each acts where its mechanism acts inside the dynamic
baseline's simulation (:mod:`capstan.models.closure.dynamic.in_model` fits them jointly with it).

=====================  ============  ===================================================
effect                 depends_on    inside the simulation
=====================  ============  ===================================================
dwell_stiction         dwell         capacity x (1 + A (1 - exp(-rest/tau_age)) exp(-slide/s0))
position_friction      position      capacity x (1 + A1 u + A2 u^2), u = (q_out - q_ref) / q_span
pretension_relaxation  time          capacity x (1 + D (1 - exp(-t_run / tau_r)))
load_friction          load          capacity x (1 + CL |tau_in| / tau_ref)
speed_viscous          velocity      drag C2 v |v| in the slip law
sensor_latency         latency       the target measured lag late (lag < 0: the drive late)
drive_gain             load          the drive (1 + eps) rho tau_in, |eps| <= GAIN_MAX: a gain error of
                                     the input load cell (testbed form only; scored jointly,
                                     below)
strain_stiffening      deflection    the cable paths K e (1 + c_node e^2), c_node >= 0, and the
                                     capacity x (1 + friction_rise (e_m / e_ref)^2) of the
                                     cables' rising mean tension (two-angle form only)
empirical:<signal>     <signal>      capacity x (1 + g(x)) and drive + h(x): piecewise-linear
                                     curves over knots at the training quantiles of x
empirical:direction    velocity      capacity x (1 + d tanh(dq_out / 2 v_rest)): a friction
                                     that differs with the direction of motion (offered with
                                     the velocity curve, one coefficient)
empirical:q_in         q_in          drive x (1 + e(q_in)), e piecewise linear over the input
                                     pulley's angle with its training mean removed (testbed
                                     form: the drive is rho tau_in)
=====================  ============  ===================================================

``strain_stiffening`` is the cable stiffening with strain, at the one-node level
(:mod:`capstan.models.transmission.hardening`: what the distributed model's cubic cable maps to,
``c_node = 4 c r^2 / (1 + 3 c D0^2)``). Two coefficients, both rises at the reference stretch
``e_ref`` (the 99.5th percentile of the stretch estimated from the target over the half cable's
stiffness, :func:`.closure.stretch_ref`), each in ``[0, RISE_MAX]``:

* ``rise`` -- of the cable path's tangent stiffness, ``3 c_node e_ref^2`` (0: the linear unit; a
  stiffening cable only); the path's linear stiffness is divided by ``1 + keep rise / 3`` with
  it (its least-squares slope over the training stretches kept, :func:`stiffening_k_scale`);
* ``friction_rise`` -- of the friction capacity, ``capacity x (1 + friction_rise (e_m /
  e_ref)^2)``: a stretch ``d`` of the pair raises both cables' mean tension by
  ``3 c D0 k_c d^2`` (the cubic law's even part) and the sheath's capstan friction with it,
  ``beta c_node e^2`` with ``beta = 3 friction_rise / rise = 3 (1 + x) / (1 + x / 3)``,
  ``x = 3 c D0^2``: between 3 and 9 for a hardening cable; a selected fit outside that is
  dropped as implausible (:func:`.closure.implausible`). ``e_m`` is half the measured
  deflection (both angles drive the two-angle form: it carries nothing the simulation does
  not see).

Both are O(0.1) on a cable that matters (the linear least-squares steps of the long-run path
start from 0 with a fixed step). Measured on the distributed model's hardening cable (T0 80 N,
c 3e5 1/m^2, x 0.68, beta 4.1): with the baseline held, the stiffness alone lowered the
held-out RMSE 11 %, with the friction term 28 %. The candidate reads no measured channel but the
driving angles, so the exclusion of the measured ``deflection`` as a second sensor of the
target does not apply to it.

``drive_gain`` is the sensor-gain sibling of ``sensor_latency``: the torque that drives the
simulation is ``(1 + eps)`` times the measured one (the input load cell reads ``1 / (1 + eps) - 1``
off), ``eps`` fitted jointly with the baseline. It is offered in the testbed form only, where the
measured tau_in drives the declared environment (in the input-predicted forms tau_in is the target
and a gain on it is ``g_out``; in the two-angle form it drives nothing). A held baseline cannot show
it: a drive scaled by ``1 + eps`` is the same model as every friction torque, the damping and the
offset divided by it, so the baseline fitted without the gain has already moved those parameters
part of the way (measured on the distributed model with a +6 % load cell: with the baseline held
the best eps is -0.015 and cuts the held-out RMSE 8 %; refitted jointly, eps -0.058 against the
injected 1 / 1.06 - 1 = -0.057, held-out -74 %). It is therefore scored *jointly*
(:attr:`InModelEffect.joint_scored`): the baseline's free parameters refitted with ``eps``, against
the same refit without it, so what is credited is the gain and not the extra refit.

``empirical:q_in`` describes what no catalogued form has: a transmitted drive torque that
varies with the input pulley's angle (an eccentric or out-of-round pulley, a radius that
changes along the groove). It is a gain, so it holds in any output environment (an additive
drive curve over an angle acts as a spring and is confounded with the environment), and
its mean is removed, so a constant gain error (a load-cell gain) is not attributed to an
angle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from capstan.models.closure.dynamic.baseline import Mods
from capstan.models.closure.residual_trace import hat_basis, knots_for
from capstan.models.closure.signals import Signals
from capstan.models.transmission.stick_slip import capacity_Nm

#: knots of an empirical in-model curve
N_KNOTS = 5
#: lag grid [ms]
LAGS_MS = (2, 5, 8, 12, 18, 25, 35, 50)
#: shapes of the dwell candidate: ageing time constant tau_age [s] x slide scale s0 [rad]
DWELL_GRID = tuple({"tau_age_s": a, "s0_rad": s0} for a in (0.5, 3.0) for s0 in (0.005, 0.02, 0.08))
#: the finer grid of the link form (factor 2 in both; measured on HIL logs of the link with
#: injected dwell stiction, tau_age 1 s, s0 0.05 rad: on the coarse grid the fit took
#: 0.5 s / 0.02 rad, its held-out RMSE was 0.109 Nm where 1 s / 0.04 rad gave 0.084 Nm, and
#: an empirical acceleration curve was then selected for what the wrong shape left)
DWELL_GRID_FINE = tuple({"tau_age_s": a, "s0_rad": s0} for a in (0.25, 0.5, 1.0, 2.0, 4.0)
                        for s0 in (0.005, 0.01, 0.02, 0.04, 0.08))

#: time constants of the pretension relaxation tried [s] (refined between neighbours, in_model)
RELAX_GRID_S = (2.0, 10.0, 50.0, 250.0)

#: plausibility bound of the drive gain's |eps| (a load cell off by more than -23 / +43 % is a
#: wiring or calibration fault, not an effect to model); a fit at the bound is reported implausible
GAIN_MAX = 0.3

#: upper bound of the stiffening's rises at e_ref (tangent stiffness, friction capacity: +300 %)
RISE_MAX = 3.0
#: plausible range of the friction coupling beta = 3 friction_rise / rise (module docstring:
#: 3 (1 + x) / (1 + x / 3) for x = 3 c D0^2 >= 0)
BETA_PLAUSIBLE = (3.0, 9.0)

ModsFn = Callable[[Signals, dict, np.ndarray], Mods]


def dwell_breakaway_excess_Nm(amp_Nm: float, tau_age_s: float, rest_s: np.ndarray | float, zeta_s: float,
                              eta_s_rad_s: float, v_rad_s: float) -> np.ndarray | float:
    """Friction a learned ``dwell_stiction`` adds at a motion onset after a rest of ``rest_s``
    [Nm]: ``amp (1 + (zeta_s - 1) exp(-(v/eta_s)^2)) (1 - exp(-rest/tau_age))`` at slide 0.

    ``amp_Nm`` scales the friction *capacity*, Stribeck peak included (the dwell candidate's
    ``cap_scale`` multiplies the unit's capacity
    :func:`~capstan.models.transmission.stick_slip.capacity_Nm`, ``tau_fc [1 + (zeta_s - 1)
    exp(-(v/eta_s)^2)]``, the same function here with ``amp`` for ``tau_fc``; the feedforward
    ``amp s(dq)``), so the breakaway excess is ``amp`` times that factor at the onset speed
    ``v_rad_s``, not ``amp`` alone (the two differ where the refit moves friction from
    ``tau_fc`` into a wide Stribeck peak: zeta_s 1.4-1.8 with eta_s ~1-4 rad/s, measured on HIL
    logs of the link). The feedforward's ``tanh(alpha dq)`` is left out: the closure's friction
    takes the sign of the motion.

    :param zeta_s: stiction ratio of the fragment's ``effects_shape`` (>= 1).
    :param eta_s_rad_s: Stribeck speed of ``effects_shape`` (> 0).
    """
    return capacity_Nm(v_rad_s, amp_Nm, zeta_s, eta_s_rad_s) * (1.0 - np.exp(-np.asarray(rest_s) / tau_age_s))



def stiffening_k_scale(rise: float, keep: float) -> float:
    """The cable path's linear stiffness multiplier ``1 / (1 + keep rise / 3)`` that goes with
    the stiffening ``rise = 3 c e_ref^2``: ``K e (1 + c e^2) / (1 + keep c e_ref^2)`` keeps the
    least-squares slope of the linear path ``K e`` over the training stretches when
    ``keep = mean(e^4) / mean(e^2) / e_ref^2`` (:attr:`Refs.stretch_keep`), so a candidate scored
    with the baseline held is not charged for the stiffness its cubic adds (measured on a
    hardening cable: with K held the search stays at 0, the held-out optimum needs K 4 % lower)."""
    return 1.0 / (1.0 + keep * rise / 3.0)


def stiffening_beta(rise: float, friction_rise: float) -> float:
    """The friction coupling ``beta = 3 friction_rise / rise`` (module docstring; NaN at ``rise = 0``)."""
    return 3.0 * friction_rise / rise if rise > 0.0 else math.nan


@dataclass(frozen=True)
class InModelEffect:
    """One candidate: ``mods(sig, shape, coef)`` builds its effect on the simulation."""

    name: str
    depends_on: tuple[str, ...]
    coef_names: tuple[str, ...]
    lo: tuple[float, ...]
    hi: tuple[float, ...]
    grid: tuple[dict, ...]
    mods: ModsFn
    empirical: bool = False
    knots: np.ndarray | None = None
    #: an empirical drive-gain curve (coefficients: the gain at the knots, mean removed)
    drive_gain: bool = False
    #: scored by a joint refit with the baseline's free parameters against the same refit
    #: without it (module docstring: ``drive_gain``), not with the baseline held
    joint_scored: bool = False


@dataclass
class Refs:
    """Training references of the effect forms (so the held-out runs use the same)."""

    q_ref_rad: float
    q_span_rad: float
    tau_ref_Nm: float
    drive_scale_Nm: float
    #: reference stretch of the unit's cable path [rad] (NaN: the form has none, no stiffening candidate)
    stretch_ref_rad: float = math.nan
    #: the stiffening candidate's ``keep`` (:func:`stiffening_k_scale`)
    stretch_keep: float = 0.6


def _run_time(sig: Signals) -> np.ndarray:
    t = np.empty(len(sig))
    for a, b in sig.segments():
        t[a:b] = sig.t_s[a:b] - sig.t_s[a]
    return t


def merge_mods(ms: list[Mods], n: int) -> Mods:
    cap = np.ones(n)
    drive = np.zeros(n)
    out = Mods()
    for m in ms:
        if m.cap_scale is not None:
            cap = cap * m.cap_scale
        if m.drive_Nm is not None:
            drive = drive + m.drive_Nm
        out.c2_Nms2_rad2 += m.c2_Nms2_rad2
        out.lag_s += m.lag_s
        out.c_node_1_rad2 += m.c_node_1_rad2
        out.k_scale *= m.k_scale
    out.cap_scale, out.drive_Nm = cap, drive
    return out


def catalogue(train: Signals, refs: Refs, excluded: dict[str, str], empirical: list[str],
              drive_gain: tuple[str, ...] = (), dwell_grid: tuple[dict, ...] = DWELL_GRID,
              gain: bool = False) -> list[InModelEffect]:
    """The in-model candidates for ``train``: the catalogue (signals in ``excluded`` left
    out), an empirical curve for each signal in ``empirical`` and a centred drive-gain
    curve for each signal in ``drive_gain`` (for the testbed form only: the drive there is
    ``ratio_q * tau_in``); ``dwell_grid``: the shapes (``tau_age_s``, ``s0_rad``) the dwell
    candidate is tried at; ``gain``: the constant ``drive_gain`` (testbed form only, the same
    drive; not offered when ``load`` is excluded)."""
    def dwell(s: Signals, sh: dict, c: np.ndarray) -> Mods:
        g = (1.0 - np.exp(-s.rest_s / sh["tau_age_s"])) * np.exp(-s.slide_rad / sh["s0_rad"])
        return Mods(cap_scale=1.0 + c[0] * g)

    def position(s: Signals, sh: dict, c: np.ndarray) -> Mods:
        u = (s.q_out_rad - refs.q_ref_rad) / refs.q_span_rad
        return Mods(cap_scale=1.0 + c[0] * u + c[1] * u * u)

    def relax(s: Signals, sh: dict, c: np.ndarray) -> Mods:
        return Mods(cap_scale=1.0 + c[0] * (1.0 - np.exp(-_run_time(s) / sh["tau_r_s"])))

    def load(s: Signals, sh: dict, c: np.ndarray) -> Mods:
        return Mods(cap_scale=1.0 + c[0] * np.abs(s.tau_in_Nm) / refs.tau_ref_Nm)

    def speed(s: Signals, sh: dict, c: np.ndarray) -> Mods:
        return Mods(c2_Nms2_rad2=float(c[0]))

    def latency(s: Signals, sh: dict, c: np.ndarray) -> Mods:
        return Mods(lag_s=float(sh["lag_s"]))

    out = [
        InModelEffect("dwell_stiction", ("dwell",), ("A",), (-0.9,), (5.0,), tuple(dwell_grid), dwell),
        InModelEffect("position_friction", ("position",), ("A1", "A2"), (-3.0, -3.0), (3.0, 3.0), ({},), position),
        InModelEffect("pretension_relaxation", ("time",), ("D",), (-0.9,), (5.0,),
                      tuple({"tau_r_s": t} for t in RELAX_GRID_S), relax),
        InModelEffect("load_friction", ("load",), ("CL",), (-0.9,), (5.0,), ({},), load),
        InModelEffect("speed_viscous", ("velocity",), ("C2_Nms2_rad2",), (0.0,), (math.inf,), ({},), speed),
        InModelEffect("sensor_latency", ("latency",), (), (), (),
                      tuple({"lag_s": sg * m / 1000.0} for m in LAGS_MS for sg in (1, -1)), latency),
    ]
    if gain:
        def drive(s: Signals, sh: dict, c: np.ndarray) -> Mods:
            return Mods(drive_Nm=float(c[0]) * s.ratio_q * s.tau_in_Nm)

        out.append(InModelEffect("drive_gain", ("load",), ("eps",), (-GAIN_MAX,), (GAIN_MAX,), ({},), drive,
                                 joint_scored=True))
    out = [e for e in out if not any(d in excluded for d in e.depends_on)]
    if math.isfinite(refs.stretch_ref_rad) and refs.stretch_ref_rad > 0.0:
        def stiffening(s: Signals, sh: dict, c: np.ndarray) -> Mods:
            rise, f_rise = float(c[0]), float(c[1])
            d = s.deflection_rad
            cap = None if d is None or f_rise == 0.0 else 1.0 + f_rise * (0.5 * d / refs.stretch_ref_rad) ** 2
            return Mods(c_node_1_rad2=rise / (3.0 * refs.stretch_ref_rad ** 2),
                        k_scale=stiffening_k_scale(rise, refs.stretch_keep), cap_scale=cap)

        # reads only the driving angles (module docstring): never excluded
        out.append(InModelEffect("strain_stiffening", ("deflection",), ("rise", "friction_rise"), (0.0, 0.0),
                                 (RISE_MAX, RISE_MAX), ({},), stiffening))
    for name in empirical:
        x = train.signal(name)
        if name in excluded or x is None or name == "deflection":
            continue
        kn = knots_for(x, N_KNOTS)
        if kn is None:
            continue
        k = kn.size

        def emp(s: Signals, sh: dict, c: np.ndarray, name: str = name, kn: np.ndarray = kn) -> Mods:
            xs = s.signal(name)
            assert xs is not None
            H = hat_basis(xs, kn)
            return Mods(cap_scale=1.0 + H @ c[:kn.size], drive_Nm=refs.drive_scale_Nm * (H @ c[kn.size:]))

        out.append(InModelEffect(f"empirical:{name}", (name,), tuple(f"g_{i}" for i in range(k)) +
                                 tuple(f"h_{i}" for i in range(k)), (-0.9,) * k + (-2.0,) * k, (5.0,) * k + (2.0,) * k,
                                 ({},), emp, empirical=True, knots=kn))
    if "velocity" in empirical and "velocity" not in excluded:
        v_dir = 2.0 * train.v_rest_rad_s

        def direction(s: Signals, sh: dict, c: np.ndarray) -> Mods:
            return Mods(cap_scale=1.0 + c[0] * np.tanh(s.dq_out_rad_s / v_dir))

        out.append(InModelEffect("empirical:direction", ("velocity",), ("d",), (-0.9,), (0.9,), ({},), direction,
                                 empirical=True))
    for name in drive_gain:
        x = train.signal(name)
        if name in excluded or x is None:
            continue
        kn = knots_for(x, N_KNOTS)
        if kn is None:
            continue
        mean_h = hat_basis(x, kn).mean(axis=0)

        def gain(s: Signals, sh: dict, c: np.ndarray, name: str = name, kn: np.ndarray = kn,
                 mean_h: np.ndarray = mean_h) -> Mods:
            xs = s.signal(name)
            assert xs is not None
            return Mods(drive_Nm=s.ratio_q * s.tau_in_Nm * ((hat_basis(xs, kn) - mean_h) @ c))

        out.append(InModelEffect(f"empirical:{name}", (name,), tuple(f"e_{i}" for i in range(kn.size)),
                                 (-0.5,) * kn.size, (0.5,) * kn.size, ({},), gain, empirical=True, knots=kn,
                                 drive_gain=True))
    return out


def _named(eff: InModelEffect, shape: dict, coef: np.ndarray, tau_fc: float, refs: Refs) -> dict[str, float]:
    """The coefficients in the feedforward's units (effects_runtime) where a catalogue form has them."""
    if eff.name == "dwell_stiction":
        return {"amp_Nm": float(coef[0] * tau_fc)}
    if eff.name == "position_friction":
        return {"a1_Nm_rad": float(coef[0] * tau_fc / refs.q_span_rad),
                "a2_Nm_rad2": float(coef[1] * tau_fc / refs.q_span_rad ** 2)}
    if eff.name == "pretension_relaxation":
        return {"d_Nm": float(coef[0] * tau_fc)}
    if eff.name == "load_friction":
        return {"c_load": float(coef[0] * tau_fc / refs.tau_ref_Nm)}
    if eff.name == "speed_viscous":
        return {"c2_Nms2_rad2": float(coef[0]), "c3_Nms3_rad3": 0.0}
    if eff.name == "drive_gain":
        # the simulation is driven by (1 + eps) tau_in: the load cell reads 1 / (1 + eps) - 1 off
        return {"eps": float(coef[0]), "load_cell_gain_error": float(1.0 / (1.0 + coef[0]) - 1.0), "eps_max": GAIN_MAX}
    if eff.name == "strain_stiffening":
        beta = stiffening_beta(float(coef[0]), float(coef[1]))
        return {"c_node_1_rad2": float(coef[0] / (3.0 * refs.stretch_ref_rad ** 2)), "stretch_ref_rad": refs.stretch_ref_rad,
                "tangent_rise_at_ref": float(coef[0]), "friction_rise_at_ref": float(coef[1]),
                "k_scale": stiffening_k_scale(float(coef[0]), refs.stretch_keep), "rise_max": RISE_MAX, "beta": beta,
                "beta_plausible": bool(BETA_PLAUSIBLE[0] <= beta <= BETA_PLAUSIBLE[1])}
    return {}
