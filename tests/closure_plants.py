"""Runs for the closure tests from *other* model families than the closure's own: the
project's distributed model (N >= 10, double-bend non-uniform curvature, eq-23 pretension
field) with effects injected into its physics, in forms other than the closure
catalogue's. Sensor noise is added to the torques (and the velocity) as a rig would.
"""

from __future__ import annotations

import math

import numpy as np

from capstan.models.common.measurement_table import MeasurementTable
from capstan.models.distributed.model import BoundaryParams, DistributedModel, TransmissionParams

R_M = 0.04
MU = 0.052


def double_bend(n_nodes: int, theta_total_rad: float = 3.0) -> np.ndarray:
    """Per-node bending angles of a routing with two bends of unequal sharpness (non-uniform)."""
    s = (np.arange(n_nodes) + 0.5) / n_nodes
    w = np.exp(-((s - 0.25) / 0.08) ** 2) + 0.6 * np.exp(-((s - 0.7) / 0.12) ** 2) + 0.05
    return theta_total_rad * w / w.sum()


def eq23_field(theta_nodes: np.ndarray, T_in_N: float, T_out_N: float, mu: float = MU) -> np.ndarray:
    """Segment pretensions of eq (23) on a non-uniform routing (larger of the two decays)."""
    cum = np.concatenate(([0.0], np.cumsum(theta_nodes)))
    return np.maximum(T_in_N * np.exp(-mu * cum), T_out_N * np.exp(-mu * (cum[-1] - cum)))


def multisine(t_s: np.ndarray, peak_Nm: float, seed: int, f_hz: tuple[float, ...] = (0.11, 0.23, 0.41, 0.73)) -> np.ndarray:
    """Sum of sines with random phases scaled to ``peak_Nm``, with rests (the joint sticks)."""
    rng = np.random.default_rng(seed)
    u = sum(np.sin(2 * np.pi * f * t_s + rng.uniform(0, 2 * np.pi)) / (1 + k) for k, f in enumerate(f_hz))
    u = u / np.max(np.abs(u)) * peak_Nm
    gate = 0.5 * (1 + np.tanh(6 * np.sin(2 * np.pi * 0.05 * t_s + rng.uniform(0, 6))))  # slow on/off: dwells
    return u * gate


class Injection:
    """An effect injected into the distributed model's physics, block by block (50 ms).

    ``mu(t, model, state) -> (2N,)`` node friction multipliers, ``u(t, model, state) -> gain``
    of the drive torque reaching the cable, ``b_node`` per-node damping [N s/m],
    ``creep(t) -> pretension change`` [N] since the start, ``post(cols)`` edits the
    measured channels (sensor effects). ``state`` is a dict the functions may keep.
    """

    def __init__(self, mu=None, u=None, b_node=None, creep=None, post=None) -> None:
        self.mu, self.u, self.b_node, self.creep, self.post = mu, u, b_node, creep, post


def distributed_run(duration_s: float = 20.0, n_nodes: int = 12, k_out: float = 20.0, b_out: float = 2.0,
                    T0_N: float = 150.0, seed: int = 0, noise_Nm: float = 0.02, noise_dq: float = 1e-3,
                    dt_s: float = 1e-3, peak_Nm: float = 6.0, inject: Injection | None = None,
                    declare_env: bool = True, source: str = "dist", block: int = 50,
                    settle_s: float = 0.2, cubic_1_m2: float = 0.0) -> tuple[MeasurementTable, dict]:
    """One testbed run of the distributed model with the four fixture tensions as extra
    channels (T_up_in, T_up_out, T_lo_out, T_lo_in), noise on the measured channels.

    The recording starts on a rig at rest: the model (built out of equilibrium: its output
    moves at -0.3 rad/s at the first sample) first settles for ``settle_s`` holding the
    run's first drive torque, unrecorded, as a rig does before its recording starts.

    ``cubic_1_m2``: a strain-hardening cable, the distributed model's cubic spring law
    ``f = k_c D (1 + c D^2)`` (:class:`DistributedModel`), set before the run with the slack
    lengths recomputed (:meth:`DistributedModel.reset`) so the pretension field is the same
    as the clean run's -- only the stiffness changes, not the friction.

    Returns (table, truth) where truth holds the noise-free torques.
    """
    th = double_bend(n_nodes)
    tens = eq23_field(th, T0_N, T0_N * 0.9)
    trans = TransmissionParams(th, th[::-1].copy(), tens, eq23_field(th[::-1], T0_N * 0.95, T0_N), mu=MU)
    model = DistributedModel(trans, BoundaryParams(k_out_Nm_rad=k_out, b_out_Nms_rad=b_out))
    if cubic_1_m2 != 0.0:
        model.stiffness_cubic_1_m2 = cubic_1_m2
        model.reset()
    t = np.arange(0.0, duration_s, dt_s)
    u = multisine(t, peak_Nm, seed)
    inj = inject or Injection()
    if inj.b_node is not None:
        model.b_node_Ns_m[:] = inj.b_node
    n_pre = int(round(settle_s / dt_s))
    if n_pre > 0:
        t_pre = np.arange(-n_pre, 1) * dt_s
        model.simulate(t_pre, np.full(t_pre.shape, u[0]), adaptive=True, rtol=1e-4, record_tensions=False)
    if inj.mu is None and inj.u is None and inj.creep is None:
        res = model.simulate(t, u, adaptive=True, rtol=1e-4)
        tin, tout, qin, qout, dqo, fix = (res.tau_in_Nm, res.tau_out_Nm, res.q_in_rad, res.q_out_rad,
                                          res.dq_out_rad_s, res.fixture_tensions_N)
    else:
        parts = []
        state: dict = {}
        shifted = 0.0
        for a in range(0, len(t) - 1, block):
            b = min(len(t), a + block + 1)
            if inj.mu is not None:
                model.mu_scale[:] = inj.mu(t[a], model, state)
            if inj.creep is not None:
                d = inj.creep(t[a]) - shifted
                model.shift_pretension(d)
                shifted += d
            g = 1.0 if inj.u is None else inj.u(t[a], model, state)
            r = model.simulate(t[a:b], g * u[a:b], adaptive=True, rtol=1e-4)
            sl = slice(0 if a == 0 else 1, None)
            # the torque sensor sits on the drive side: with an eccentric pulley it reads the
            # drive torque u, not the cable torque g u
            parts.append((u[a:b][sl] if inj.u is not None else r.tau_in_Nm[sl], r.tau_out_Nm[sl], r.q_in_rad[sl], r.q_out_rad[sl], r.dq_out_rad_s[sl],
                          r.fixture_tensions_N[sl]))
        tin, tout, qin, qout, dqo = (np.concatenate([p[i] for p in parts]) for i in range(5))
        fix = np.concatenate([p[5] for p in parts])
    rng = np.random.default_rng(1000 + seed)
    n = len(t)
    cols = {"t": t, "tau_in": tin + noise_Nm * rng.standard_normal(n), "tau_out": tout + noise_Nm * rng.standard_normal(n),
            "q_in": qin.copy(), "q_out": qout.copy(), "dq_out": dqo + noise_dq * rng.standard_normal(n)}
    for j, nm in enumerate(("T_up_in", "T_up_out", "T_lo_out", "T_lo_in")):
        cols[nm] = fix[:, j] + 0.5 * rng.standard_normal(n)
    if inj.post is not None:
        inj.post(cols)
    meta = {"r_in": R_M, "r_out": R_M}
    if declare_env:
        meta["environment"] = {"k_out": k_out, "b_out": b_out}
    return MeasurementTable(cols, meta, source), {"tau_out": tout, "tau_in": tin}
