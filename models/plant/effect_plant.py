"""Simulated testbed runs with a physical effect injected into the plant that the
identified model does not have (for the closure tests and demonstrations).

Plant: the torsional unit of eq (20) with the eq (21) friction and the testbed output
of eq (22) (``models.reduced.reduced_step``, backward Euler at 1 ms), driven by an
input-torque multisine with hold phases (:class:`ExcitationDesign`: the slow default
``MULTISINE_HOLDS``, or ``FAST_MULTISINE`` for speed- and rate-dependent effects).
Effects are injected *between steps*, as the physical mechanism would act:

=====================  ============================================================
effect                 injection
=====================  ============================================================
dwell_stiction         tau_fc x (1 + A (1 - exp(-rest/tau_age)) exp(-slide/s0))
speed_viscous          viscous coefficient grows with speed: b_vis + c |dq|, i.e. a
                       drag c dq|dq| (lumped distributed shear drag at speed)
position_friction      tau_fc x (1 + a1 q + a2 q^2) (routing bends with the joint)
pretension_relaxation  tau_fc x (1 - d (1 - exp(-t/tau_r))) (T0 relaxes, creep)
sensor_latency         the measured dq_out channel (IMU) is delayed by ``lag_s``
nonlinear_stiffness    cable deflection solves K_c x + K3 x^3 = (tau_in + tau_out)/2
load_friction          tau_fc x (1 + c |tau_in|) (capstan: friction grows with load)
temperature_drift      tau_fc x (1 + c (T - 25 degC)), T a slowly wandering channel
friction_ripple        NOT catalogued: tau_fc x (1 + A sin(2 pi q / P)), P = 0.23 rad
=====================  ============================================================

Measured channels carry white noise (tau 0.02 Nm, dq_out 0.001 rad/s (IMU rate of turn, filtered), q 1e-4 rad).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from capstan.models.common.errors import ModelError
from capstan.models.plant.injected_friction import friction_multiplier, plant_dwell_step
from capstan.models.transmission.reduced import reduced_step
from capstan.models.common.measurement_table import MeasurementTable

INJECTABLE = ("none", "dwell_stiction", "speed_viscous", "position_friction", "pretension_relaxation",
              "sensor_latency", "nonlinear_stiffness", "load_friction", "temperature_drift", "friction_ripple")


@dataclass(frozen=True)
class PlantParams:
    """Nominal plant (eq 20-22); defaults are the reference rig's orders of magnitude."""

    tau_fc_Nm: float = 1.5
    zeta_s: float = 1.3
    eta_s_rad_s: float = 0.05
    alpha_s_rad: float = 30.0
    b_vis_Nms_rad: float = 0.1
    gamma_Nms_rad: float = 0.05
    k_out_Nm_rad: float = 20.0
    b_out_Nms_rad: float = 2.0
    K_c_Nm_rad: float = 240.0
    noise_tau_Nm: float = 0.02
    noise_dq_rad_s: float = 0.001
    noise_q_rad: float = 1e-4


@dataclass(frozen=True)
class Injection:
    """One injected effect and its strength (``params`` per effect, see module table)."""

    effect: str = "none"
    params: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.effect not in INJECTABLE:
            raise ModelError(f"unknown injected effect {self.effect!r}; one of {', '.join(INJECTABLE)}")


#: default strengths (large enough to matter, physically plausible)
DEFAULTS: dict[str, dict[str, float]] = {
    "dwell_stiction": {"amp": 1.5, "tau_age_s": 1.0, "slide_rad": 0.05},
    "speed_viscous": {"c_Nms2_rad2": 2.0},
    "position_friction": {"a1_1_rad": 0.5, "a2_1_rad2": 0.6},
    "pretension_relaxation": {"drop": 0.4, "tau_r_s": 40.0},
    "sensor_latency": {"lag_s": 0.012},
    "nonlinear_stiffness": {"K3_Nm_rad3": 8.0e4},
    "load_friction": {"c_1_Nm": 0.12},
    "temperature_drift": {"c_1_K": 0.04},
    "friction_ripple": {"amp": 0.35, "period_rad": 0.23},
}


@dataclass(frozen=True)
class ExcitationDesign:
    """How the input-torque excitation is designed (same torque amplitudes, ~8 Nm peak).

    :ivar freq_scale: multiplies the multisine's frequencies (0.21-1.37 Hz at 1); faster
        excitation drives the joint to higher speeds.
    :ivar hold_scale: multiplies the hold (rest) durations (0.1-4 s at 1; 0: no holds).
    """

    freq_scale: float = 1.0
    hold_scale: float = 1.0

    def __post_init__(self) -> None:
        if not (self.freq_scale > 0.0 and self.hold_scale >= 0.0):
            raise ModelError(f"excitation needs freq_scale > 0 and hold_scale >= 0, got {self}")


#: the default: slow multisine with long holds (stiction, dwell, rest behaviour)
MULTISINE_HOLDS = ExcitationDesign()
#: the experiment for speed- and rate-dependent effects: the multisine at 3x the
#: frequencies (0.6-4.1 Hz) with short holds (0.03-1.2 s), so the joint spends most of
#: the run moving, at up to ~1.3-2.3 rad/s. Drag that grows with speed is indistinguishable
#: from the linear viscous term in the slow, hold-heavy default (the paper's own caveat:
#: distributed viscous damping was not isolated "due to the limited velocity range"), and
#: a time shift between channels is invisible while the joint rests.
FAST_MULTISINE = ExcitationDesign(freq_scale=3.0, hold_scale=0.3)


def excitation(duration_s: float, rng: np.random.Generator, dt_s: float = 1e-3,
               design: ExcitationDesign = MULTISINE_HOLDS) -> tuple[np.ndarray, np.ndarray]:
    """Input torque: multisine (0.2-1.5 Hz x freq_scale, ~8 Nm peak) with random holds of
    0.1-4 s (x hold_scale). Returns (t [s], tau_in [Nm])."""
    n = int(round(duration_s / dt_s))
    t = np.arange(n) * dt_s
    clock = np.empty(n)
    c, i, moving = 0.0, 0, True
    while i < n:
        seg = rng.uniform(2.0, 5.0) if moving else rng.uniform(0.1, 4.0) * design.hold_scale
        m = min(n - i, int(seg / dt_s))
        clock[i:i + m] = c + (np.arange(m) * dt_s if moving else 0.0)
        if moving:
            c += m * dt_s
        i += m
        moving = not moving
    freqs = np.array([0.21, 0.37, 0.61, 0.93, 1.37]) * design.freq_scale
    amps = np.array([4.0, 2.5, 1.5, 1.0, 0.6])
    ph = rng.uniform(0, 2 * np.pi, freqs.size)
    u = (amps[None, :] * np.sin(2 * np.pi * freqs[None, :] * clock[:, None] + ph[None, :])).sum(axis=1)
    u *= 0.5 - 0.5 * np.cos(np.pi * np.clip(t / 1.0, 0.0, 1.0))
    return t, u


@njit(cache=True)
def _run(t, u, temp, kind, p0, p1, p2, tau_fc, zs, eta, alpha, bvis, gamma, k_out, b_out, v_rest,
         q_out, dq_out):
    n = t.shape[0]
    q, v = 0.0, 0.0
    dwell, rest, slide = 10.0, 10.0, 0.0
    for i in range(n):
        dt = t[1] - t[0] if i == 0 else t[i] - t[i - 1]
        m = friction_multiplier(kind, p0, p1, p2, q, rest, slide, t[i], u[i], temp[i])
        b = bvis + p0 * abs(v) if kind == 2 else bvis     # speed viscous (semi-implicit in |dq|)
        q, v = reduced_step(q, v, u[i], dt, 1.0, tau_fc * m, zs, 1.0, eta, alpha, b, gamma, k_out, b_out)
        dwell, rest, slide = plant_dwell_step(dwell, rest, slide, v, dt, v_rest)
        q_out[i] = q
        dq_out[i] = v


def simulate_run(injection: Injection, duration_s: float = 60.0, seed: int = 0,
                 plant: PlantParams = PlantParams(), t0_s: float = 0.0,
                 design: ExcitationDesign = MULTISINE_HOLDS) -> MeasurementTable:
    """Simulate one testbed run with ``injection`` and return it as a measurement table.

    ``t0_s`` offsets the session clock (a later run of the same session: the effects
    that depend on time continue); ``design`` chooses the excitation. Columns: t, tau_in,
    tau_out, q_in, q_out, dq_out, plus ``temperature`` [degC] for temperature_drift.

    :raises ModelError: on an unknown effect or a failed integration.
    """
    rng = np.random.default_rng(seed)
    t, u = excitation(duration_s, rng, design=design)
    t = t + t0_s
    prm = {**DEFAULTS.get(injection.effect, {}), **injection.params}
    vals = list(prm.values()) + [1.0, 1.0, 1.0]
    kind = INJECTABLE.index(injection.effect)
    ph = rng.uniform(0, 2 * np.pi, 2)
    temp = 25.0 + 8.0 * np.sin(2 * np.pi * t / 47.0 + ph[0]) + 4.0 * np.sin(2 * np.pi * t / 13.0 + ph[1])
    n = t.size
    q, v = np.empty(n), np.empty(n)
    pl = plant
    _run(t, u, temp, kind, float(vals[0]), float(vals[1]), float(vals[2]), pl.tau_fc_Nm, pl.zeta_s,
         pl.eta_s_rad_s, pl.alpha_s_rad, pl.b_vis_Nms_rad, pl.gamma_Nms_rad, pl.k_out_Nm_rad,
         pl.b_out_Nms_rad, 0.02, q, v)
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
        raise ModelError(f"effect plant integration failed ({injection.effect})")
    tau_out = pl.k_out_Nm_rad * q + pl.b_out_Nms_rad * v
    mean_torque = 0.5 * (u + tau_out)
    defl = mean_torque / pl.K_c_Nm_rad
    if injection.effect == "nonlinear_stiffness":
        k3 = prm["K3_Nm_rad3"]
        for _ in range(30):     # Newton on K x + K3 x^3 = tau (monotone)
            defl -= (pl.K_c_Nm_rad * defl + k3 * defl ** 3 - mean_torque) / (pl.K_c_Nm_rad + 3 * k3 * defl ** 2)
    tau_out_meas = tau_out.copy()
    dq_meas = v.copy()
    if injection.effect == "sensor_latency":
        lag = int(round(prm["lag_s"] / (t[1] - t[0])))
        dq_meas = np.concatenate([np.full(lag, v[0]), v[:-lag]]) if lag > 0 else dq_meas
    cols = {
        "t": t,
        "tau_in": u + rng.normal(0, pl.noise_tau_Nm, n),
        "tau_out": tau_out_meas + rng.normal(0, pl.noise_tau_Nm, n),
        "q_in": q + defl + rng.normal(0, pl.noise_q_rad, n),
        "q_out": q + rng.normal(0, pl.noise_q_rad, n),
        "dq_out": dq_meas + rng.normal(0, pl.noise_dq_rad_s, n),
    }
    if injection.effect == "temperature_drift":
        cols["temperature"] = temp + rng.normal(0, 0.05, n)
    meta = {"r_in": 0.04, "r_out": 0.04, "environment": {"k_out": pl.k_out_Nm_rad, "b_out": pl.b_out_Nms_rad},
            "injected": {"effect": injection.effect, "params": {k: float(x) for k, x in prm.items()}},
            "excitation": {"freq_scale": design.freq_scale, "hold_scale": design.hold_scale},
            "units": {"temperature": "degC"}}
    return MeasurementTable(cols, meta, f"sim:{injection.effect}:seed{seed}")
