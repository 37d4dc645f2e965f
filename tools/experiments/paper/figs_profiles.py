"""Paper Fig. 8 on the simulated rig: distributed tension and displacement profiles over time,
and the transmission friction against input and output velocity.

Node displacements are reconstructed from the recorded segment tensions: along each cable the
end displacement ``r q_in`` is propagated through the segment elongation changes
``(f - f(0)) / k_seg`` (upper cable wound in: ``x_{i+1} = x_i - df_i / k``; lower cable paid
out: ``x_{i+1} = x_i + df_i / k``); the reconstruction must land on ``r q_out`` at the output end
(reported as the closure error, a consistency check of tensions and angles).

Friction torque ``tau_f = tau_in - rho tau_out`` (massless output pulley, rho = 1). Against the
input velocity it is hysteretic (the input moves while parts of the cables still stick), against
the output velocity Coulomb-like. Measured by the relative residual of the best Coulomb fit
``F tanh(v / v_s)`` (``v_s`` = 2 % of the velocity range): small means Coulomb-like.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from capstan.tools.experiments.paper.common import (K_C_NM_RAD, OUTPUTS, R_M, Run, Settings, group_routing, row, save,  # noqa: E402
                                     simulate_plant, sine)


def displacement_profiles_m(run: Run) -> tuple[np.ndarray, np.ndarray]:
    """(upper, lower) node displacements (n_samples, N+2) [m] from the tensions; the last
    column is the reconstructed output end, to be compared with ``r q_out``.

    :raises ValueError: if the run carries no tension profiles.
    """
    if run.tensions_upper_N is None or run.tensions_lower_N is None:
        raise ValueError("the run was simulated without record_tensions")
    n = run.tensions_upper_N.shape[1] - 1
    k_seg = (n + 1) * K_C_NM_RAD / (2.0 * R_M * R_M)
    x0 = R_M * run.q_in_rad[:, None]
    du = (run.tensions_upper_N - run.tensions_upper_N[0]) / k_seg
    dl = (run.tensions_lower_N - run.tensions_lower_N[0]) / k_seg
    xu = np.concatenate((x0, x0 - np.cumsum(du, axis=1)), axis=1)
    xl = np.concatenate((x0, x0 + np.cumsum(dl, axis=1)), axis=1)
    return xu, xl


def coulomb_residual(v: np.ndarray, tau_f: np.ndarray) -> tuple[float, float]:
    """Best ``F tanh(v / v_s)`` fit: (F [Nm], RMS residual / F [-])."""
    vs = 0.02 * float(np.ptp(v))
    s = np.tanh(v / vs)
    F = float(np.dot(s, tau_f) / np.dot(s, s))
    return F, float(np.sqrt(np.mean((tau_f - F * s) ** 2)) / abs(F))


def fig8(settings: Settings, out_dir: Path) -> dict[str, Any]:
    """Profiles over time (image plots) and friction vs input / output velocity."""
    t0 = time.perf_counter()
    r = group_routing(2)
    run = simulate_plant(r, sine(8.0, 0.2), settings, OUTPUTS["stiff"], duration_s=11.0, record_tensions=True,
                         seed_offset=80)
    xu, xl = displacement_profiles_m(run)
    # closure: the noise-free output angle is not stored; compare with the noisy measurement
    closure = float(np.max(np.abs(np.stack((xu[:, -1], xl[:, -1])) - R_M * run.q_out_rad)))
    i0 = int(np.searchsorted(run.t_s, 3.0))
    tau_f = (run.tau_in_Nm - run.tau_out_Nm)[i0:]
    F_in, res_in = coulomb_residual(run.dq_in_rad_s[i0:], tau_f)
    F_out, res_out = coulomb_residual(run.dq_out_rad_s[i0:], tau_f)
    fig, axes = plt.subplots(2, 3, figsize=(14, 7))
    ext = [run.t_s[0], run.t_s[-1], 0.0, 1.0]
    for ax, img, title in ((axes[0, 0], run.tensions_upper_N, "(c) upper cable tension [N]"),
                           (axes[1, 0], run.tensions_lower_N, "(c) lower cable tension [N]"),
                           (axes[0, 1], (xu - xu[:, :1]) * 1e3, "(d) upper cable x − r q_in [mm]"),
                           (axes[1, 1], (xl - xl[:, :1]) * 1e3, "(d) lower cable x − r q_in [mm]")):
        im = ax.imshow(img.T, aspect="auto", origin="lower", extent=ext, cmap="viridis")
        ax.set(xlabel="t [s]", ylabel="s / L (input -> output)", title=title)
        fig.colorbar(im, ax=ax)
    axes[0, 2].plot(run.dq_in_rad_s[i0:], tau_f, lw=0.5)
    axes[0, 2].set(xlabel="dq_in [rad/s]", ylabel="τ_in − τ_out [Nm]",
                   title=f"(e) vs input velocity: resid/F = {res_in:.2f}")
    axes[1, 2].plot(run.dq_out_rad_s[i0:], tau_f, lw=0.5)
    axes[1, 2].set(xlabel="dq_out [rad/s]", ylabel="τ_in − τ_out [Nm]",
                   title=f"(f) vs output velocity: resid/F = {res_out:.2f}")
    png = save(fig, out_dir, "fig8_profiles.png")
    prox = run.tensions_upper_N[i0:, 0]
    dist = run.tensions_upper_N[i0:, -1]
    rows = [
        row("friction vs input velocity: Coulomb-fit residual / F", None, res_in, "-",
            "hysteretic: the input moves while distal segments still stick"),
        row("friction vs output velocity: Coulomb-fit residual / F", None, res_out, "-",
            "Coulomb-like (paper Fig. 8 f): the output velocity is the better friction state"),
        row("tension swing distal / proximal (upper cable)", None, float(np.ptp(dist) / np.ptp(prox)), "-",
            "tension propagation attenuates toward the output (paper Fig. 8 c)"),
        row("displacement reconstruction closure error", None, closure * 1e3, "mm",
            "node displacements from tensions land on r q_out (includes the IMU angle noise)"),
    ]
    return {"title": "Fig. 8: distributed profiles and friction vs velocity", "rows": rows, "figures": [png],
            "data": {"theta_rad": r.theta_total_rad, "coulomb_F_in_Nm": F_in, "coulomb_F_out_Nm": F_out,
                     "resid_in": res_in, "resid_out": res_out, "closure_mm": closure * 1e3},
            "wall_s": time.perf_counter() - t0}
