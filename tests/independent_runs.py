"""Rig runs from the independent plant (tests/independent_plant.py) for the closure tests:
effects written in this module's own forms (not the closure catalogue's,
models/closure/effects.py and models/closure/dynamic/candidates.py), sensors as a rig has
them, as :class:`MeasurementTable` (the closure's input format).

The rig: a motor (J_m 0.73 kg m^2, b_m 2 N m s/rad) drives the input pulley with a torque
``tau_m``; the transmission is 12 nodes per cable on a two-bend curvature profile over the
1.379 m routing (both sheaths follow the same path), pretension from eq (23) with unequal
fixture tensions; the output drives the testbed environment (k_out, b_out). Sensors: the
four fixture load cells (0.5 N noise; tau_in is r_in times the input pair's difference, as
the rig computes it), an output torque sensor (0.02 Nm noise), the motor encoder (2^17
counts/rev), the output angle (2e-5 rad noise) and gyro rate (1e-3 rad/s noise).

Excitation: a multisine on a clock that stops -- the drive holds its torque for 0.5-2.5 s
every few seconds, so the joint rests under a held, non-zero torque (dwells under load).

Effects (:data:`EFFECTS`), each a physical change inside the plant or its sensors:

* ``dwell_load`` -- junction ageing: each node's friction coefficient is ``mu (1 + a_j)``;
  ``a_j`` grows towards ``0.6 min(1, |tau_m| / 2 Nm)`` with a 1 s time constant (faster the
  more load is held) and is erased by the node's own slip over 0.1 mm
  (``da/dt = (A L - a) / tau - a |v_j| / s0``, a rate-and-state ageing law);
* ``node_drag`` -- sheath drag in each node's sliding speed, ``c2 v_j |v_j|`` (5000 N s^2/m^2: 1.4 N per node at 17 mm/s, about its Coulomb level);
* ``reroute_step`` -- at mid-run the second bend is re-routed 50 % tighter: the bends of the
  nodes beyond half the routing's bending (the second bend and what follows) x 1.5 from
  that instant;
* ``relaxation`` -- the pretension field relaxes by 35 % exponentially, time constant 4 s
  (stress relaxation: every segment scaled, not shifted);
* ``load_cell_gain`` -- both input load cells read 6 % high (so does tau_in).
"""

from __future__ import annotations

import numpy as np

from capstan.models.common.measurement_table import MeasurementTable
from tests.independent_plant import MOTOR, TESTBED, Plant, capstan_field, node_bends, simulate

R_M = 0.04
MU = 0.052
LENGTH_M = 1.379
DT_S = 1e-3
EFFECTS = ("none", "dwell_load", "node_drag", "reroute_step", "relaxation", "load_cell_gain")
ENCODER_RAD = 2.0 * np.pi / 2 ** 17


def _bends(s_m: np.ndarray) -> np.ndarray:
    return np.exp(-((s_m - 0.35) / 0.09) ** 2) + 0.5 * np.exp(-((s_m - 1.0) / 0.15) ** 2) + 0.04


def curvature(s_m: np.ndarray, theta_rad: float = 3.0) -> np.ndarray:
    """Two bends of unequal sharpness on a slight background curvature [1/m], scaled so
    that the routing bends ``theta_rad`` in all."""
    s = np.linspace(0.0, LENGTH_M, 4001)
    w = _bends(s)
    return theta_rad * _bends(s_m) / float(np.sum((w[1:] + w[:-1]) * 0.5 * np.diff(s)))


def rig_plant(k_out: float, b_out: float, n_nodes: int = 12, T0_N: float = 150.0, drag_c2: float = 0.0) -> Plant:
    """The rig's plant (module docstring) with the testbed environment (k_out, b_out)."""
    th = node_bends(curvature, LENGTH_M, n_nodes)
    return Plant(th, th.copy(), capstan_field(th, T0_N, 0.9 * T0_N, MU), capstan_field(th, 0.95 * T0_N, T0_N, MU),
                 mu=MU, r_in=R_M, r_out=R_M, drag_c2=drag_c2, input_mode=MOTOR, output_mode=TESTBED,
                 k_out=k_out, b_out=b_out)


def held_multisine(t_s: np.ndarray, peak_Nm: float, seed: int) -> np.ndarray:
    """Motor torque [Nm]: four sines with random phases on a clock that stops for 0.5-2.5 s
    holds (ramped over 0.1 s) after 1.5-3.5 s of motion."""
    rng = np.random.default_rng(seed)
    rate = np.ones_like(t_s)
    t0 = rng.uniform(0.8, 2.0)
    while t0 < t_s[-1]:
        hold = rng.uniform(0.5, 2.5)
        ramp_in = np.clip((t_s - t0) / 0.1, 0.0, 1.0)
        ramp_out = np.clip((t_s - t0 - hold) / 0.1, 0.0, 1.0)
        rate = np.minimum(rate, 1.0 - ramp_in + ramp_out)
        t0 += hold + 0.1 + rng.uniform(1.5, 3.5)
    clock = np.concatenate(([0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t_s))))
    freqs = (0.13, 0.29, 0.47, 0.71)
    u = sum(np.sin(2 * np.pi * f * clock + rng.uniform(0, 2 * np.pi)) / (1 + k) for k, f in enumerate(freqs))
    return peak_Nm * u / np.max(np.abs(u))


def rig_run(effect: str, seed: int, k_out: float, b_out: float, seconds: float = 10.0, source: str = "",
            settle_s: float = 0.3, peak_Nm: float = 7.0, n_nodes: int = 12) -> tuple[MeasurementTable, dict]:
    """One recorded run with ``effect`` (one of :data:`EFFECTS`); the plant first settles for
    ``settle_s`` at the first motor torque, unrecorded. Returns (table, truth)."""
    if effect not in EFFECTS:
        raise ValueError(f"unknown effect {effect!r}")
    P = rig_plant(k_out, b_out, n_nodes, drag_c2=5000.0 if effect == "node_drag" else 0.0)
    t = np.arange(0.0, seconds, DT_S)
    u = held_multisine(t, peak_Nm, seed)
    t_pre = np.arange(-int(round(settle_s / DT_S)), 1) * DT_S
    pre = simulate(P, t_pre, np.full(t_pre.shape, u[0]))
    kw: dict = {}
    if effect == "dwell_load":
        kw = dict(age_amp=0.6, age_tau_s=1.0, age_s0_m=1e-4, age_drive=np.minimum(1.0, np.abs(u) / 2.0))
    elif effect == "relaxation":
        kw = dict(s_T=1.0 - 0.35 * (1.0 - np.exp(-t / 4.0)))
    elif effect == "reroute_step":
        bend = np.ones((len(t), 2 * P.n))
        second = np.concatenate([P.theta_up.cumsum() > 0.5 * P.theta_up.sum()] * 2)
        bend[np.ix_(t >= 0.5 * seconds, second)] = 1.5
        kw = dict(bend=bend)
    r = simulate(P, t, u, y0=pre.y_end, **kw)
    if r.newton_failures:
        raise RuntimeError(f"{effect} seed {seed}: {r.newton_failures} steps without Newton convergence")
    rng = np.random.default_rng(7919 * seed + 17)
    n = len(t)
    fix = r.fixture + 0.5 * rng.standard_normal((n, 4))
    if effect == "load_cell_gain":
        fix[:, [0, 3]] *= 1.06
    cols = {"t": t, "tau_in": R_M * (fix[:, 0] - fix[:, 3]), "tau_out": r.tau_out + 0.02 * rng.standard_normal(n),
            "q_in": np.round(r.q_in / ENCODER_RAD) * ENCODER_RAD, "q_out": r.q_out + 2e-5 * rng.standard_normal(n),
            "dq_out": r.dq_out + 1e-3 * rng.standard_normal(n)}
    for j, name in enumerate(("T_up_in", "T_up_out", "T_lo_out", "T_lo_in")):
        cols[name] = fix[:, j]
    meta = {"r_in": R_M, "r_out": R_M, "environment": {"k_out": k_out, "b_out": b_out}}
    return (MeasurementTable(cols, meta, source or f"indep-{effect}-{seed}"),
            {"tau_out": r.tau_out, "tau_in": r.tau_in, "u": u, "run": r})
