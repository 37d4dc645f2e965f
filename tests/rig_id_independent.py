"""Test helper: the independent dense transmission (tests/independent_distributed.py, written from
the paper, no package code) between a motor inertia and a pendulum link, driven by an
identification excitation, with the sensors a rig has (quantised encoder, noisy load cells,
IMU at 400 Hz).

The boundaries are the paper's eq (2) and (4) with inertia (a motor J_m ddq_in + b_m dq_in =
tau_m - tau_in and a link J_l ddq_out + b_l dq_out = tau_out - m g l sin q_out + tau_ext); the
transmission's matrices and friction law are the independent model's own. The excitation's law
is applied continuously on the true motor state (the open-loop multisine interpolated, the free
run's PD on the exact angle); the logged command is that law at the sample times.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from tests.independent_distributed import IndepModel, uniform_params

CLAMP_K_NM_RAD = 5000.0
CLAMP_B_NMS_RAD = 50.0


class IndependentRig:
    """Motor + independent transmission + pendulum link (SI).

    :param n_nodes: internal nodes per cable; the other keywords go to ``uniform_params``.
    """

    def __init__(self, K_c: float, mu: float, J_m: float, b_m: float, J_l: float, b_l: float, m_g_l: float,
                 theta_rad: float = 3.0, T0_N: float = 150.0, n_nodes: int = 4, r_m: float = 0.04) -> None:
        self.tm = IndepModel(uniform_params(n_nodes, theta_rad, T0_N, K_c=K_c, mu=mu, r_in=r_m, r_out=r_m))
        self.J_m, self.b_m, self.J_l, self.b_l, self.mgl = J_m, b_m, J_l, b_l, m_g_l
        self.r_m = r_m

    def _law(self, exc, held: bool):
        dt = exc.dt_s
        t_grid = np.arange(exc.n_cycles) * dt
        ff = exc.feedforward_Nm
        qr = exc.q_ref_rad
        lim = exc.limits.tau_max_Nm

        n = len(t_grid)

        def interp(x: np.ndarray, t: float) -> float:
            i = min(max(int(t / dt), 0), n - 2)
            w = min(max(t / dt - i, 0.0), 1.0)
            return float(x[i] + w * (x[i + 1] - x[i]))

        def tau(t: float, q: float, dq: float) -> tuple[float, float, float]:
            """(torque, d torque / d q, d torque / d dq) at time t for motor state q, dq."""
            u = interp(ff, t)
            dq_dq = dv_dq = 0.0
            if qr is not None:
                u += exc.kp_Nm_rad * (interp(qr, t) - q) - exc.kd_Nms_rad * dq
                dq_dq, dv_dq = -exc.kp_Nm_rad, -exc.kd_Nms_rad
            if abs(u) > lim:
                return math.copysign(lim, u), 0.0, 0.0
            return u, dq_dq, dv_dq
        return tau

    def simulate(self, exc, held: bool, rtol: float = 1e-6) -> dict[str, np.ndarray]:
        """Integrate the run; returns the exact signals at the loop's sample times (the sensors do not
        feed back: the excitation's law acts on the exact state, so one trajectory serves every noise seed)."""
        m = self.tm
        ny = m.ny
        law = self._law(exc, held)
        kx, bx = (CLAMP_K_NM_RAD, CLAMP_B_NMS_RAD) if held else (0.0, 0.0)

        def split(z):
            """(node state y, dq_in, dq_out, friction's (F, dF/ds, dF/dn), s, n)."""
            y = z[:ny]
            s = m.Sy @ y + m.Sc
            n = m.Ny @ y + m.Nc
            return y, z[ny], z[ny + 1], m._fric(s, n), s, n

        def rhs(t, z):
            y, dq_in, dq_out, (F, _, _), s, _ = split(z)
            dz = np.empty_like(z)
            dz[0] = dq_in
            dz[1:ny - 1] = (s - F) / m.P.b_node
            dz[ny - 1] = dq_out
            u, _, _ = law(t, y[0], dq_in)
            tau_in = m.Tin_y @ y + m.Tin_c
            tau_out = m.Tout_y @ y + m.Tout_c
            dz[ny] = (u - self.b_m * dq_in - tau_in) / self.J_m
            dz[ny + 1] = (tau_out - self.b_l * dq_out - self.mgl * math.sin(y[-1]) - kx * y[-1] - bx * dq_out) / self.J_l
            return dz

        def jac(t, z):
            y, dq_in, _, (_, dFds, dFdn), _, _ = split(z)
            J = np.zeros((ny + 2, ny + 2))
            J[0, ny] = 1.0
            J[1:ny - 1, :ny] = (m.Sy - dFds[:, None] * m.Sy - dFdn[:, None] * m.Ny) / m.P.b_node
            J[ny - 1, ny + 1] = 1.0
            _, du_dq, du_dv = law(t, y[0], dq_in)
            J[ny, :ny] = -m.Tin_y / self.J_m
            J[ny, 0] += du_dq / self.J_m
            J[ny, ny] = (du_dv - self.b_m) / self.J_m
            J[ny + 1, :ny] = m.Tout_y / self.J_l
            J[ny + 1, ny - 1] -= (self.mgl * math.cos(y[-1]) + kx) / self.J_l
            J[ny + 1, ny + 1] = -(self.b_l + bx) / self.J_l
            return J

        t = np.arange(exc.n_cycles) * exc.dt_s
        z0 = np.concatenate([m.y0, [0.0, 0.0]])
        atol = np.full(ny + 2, 1e-12)
        atol[[0, ny - 1]] = 1e-9
        atol[ny:] = 1e-7
        sol = solve_ivp(rhs, (t[0], t[-1]), z0, method="LSODA", t_eval=t, rtol=rtol, atol=atol, jac=jac)
        if not sol.success:
            raise RuntimeError(sol.message)
        Z = sol.y
        f = m.Af @ Z[:ny] + m.fc[:, None]         # segment tensions, upper 0..N, lower (paper order) N+1..2N+1
        N = m.N
        tau_cmd = np.array([law(ti, qi, vi)[0] for ti, qi, vi in zip(t, Z[0], Z[ny])])
        return {"t": t, "T": np.column_stack([f[0], f[N], f[N + 1], f[2 * N + 1]]), "q_in": Z[0], "dq_in": Z[ny],
                "q_out": Z[ny - 1], "dq_out": Z[ny + 1], "tau_cmd": tau_cmd}


def sample(traj: dict[str, np.ndarray], seed: int, cpr: int = 1 << 17, tension_noise_N: float = 0.3,
           imu_hz: float = 400.0, angle_noise_rad: float = 5e-4, rate_noise_rad_s: float = 2e-3) -> dict[str, np.ndarray]:
    """The record columns a rig's sensors give for ``traj`` (noise seeded ``seed``)."""
    t = traj["t"]
    rng = np.random.default_rng(seed)
    T = traj["T"] + rng.normal(0.0, tension_noise_N, (len(t), 4))
    q_in, dq_in, tau_cmd = traj["q_in"], traj["dq_in"], traj["tau_cmd"]
    step = 2.0 * math.pi / cpr
    imu_idx = np.floor(t * imu_hz + 1e-9).astype(int)
    new = np.r_[True, np.diff(imu_idx) > 0]
    pick = np.maximum.accumulate(np.where(new, np.arange(len(t)), 0))
    q_o = traj["q_out"] + rng.normal(0.0, angle_noise_rad, len(t))
    dq_o = traj["dq_out"] + rng.normal(0.0, rate_noise_rad_s, len(t))
    return {"t_s": t, "q_m_rad": np.round(q_in / step) * step, "dq_m_rad_s": dq_in, "tau_m_cmd_Nm": tau_cmd,
            "T_up_in_N": T[:, 0], "T_up_out_N": T[:, 1], "T_lo_out_N": T[:, 2], "T_lo_in_N": T[:, 3],
            "q_out_rad": q_o[pick], "dq_out_rad_s": dq_o[pick], "imu_new": new.astype(float)}
