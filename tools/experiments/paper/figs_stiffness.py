"""Paper Figs. 6 and 7 on the simulated rig: effective stiffness, hysteresis vs pretension,
bending and output dynamics, and the tension-transmission slopes against e^{-/+ mu theta}.

Metrics (computed on measured, noisy runs of the ground-truth plant):

* **effective stiffness** (Fig. 6): least-squares slope of ``tau_in`` on the deflection
  ``q_in - q_out`` over the loading-branch samples (``|tau_in|`` growing) with
  ``|tau_in| > 0.6 max |tau_in|`` (the asymptotic part of the loop, away from the
  zero-deflection crossings where the ratio is meaningless, footnote 2). While the input
  torque stays inside the stick band ``2 tau_fc`` only part of each cable engages and the
  slope is steeper (paper Fig. 8 b); the asymptote is reached when the peak torque is well
  above ``2 tau_fc``;
* **hysteresis height** (Fig. 7 a/b/d/e): ``tau_out`` at the falling minus at the rising zero
  crossings of ``tau_in`` (the intercepts at ``tau_in = 0``), averaged over the crossings after
  the first period; eq (19) predicts ``2 tau_fc = 2 mu theta T0_eq r`` on a sliding branch;
* **tension-transmission slope** (Fig. 7 c/f): slope through the origin of the upper cable's
  output-side on its input-side fixture tension while the output moves forward (cable pulled,
  theory ``e^{-mu theta}``) or backward (cable released, ``e^{+mu theta}``).
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from capstan.models.transmission.pretension import pretension_field  # noqa: E402
from capstan.tools.experiments.paper.common import (K_C_NM_RAD, LENGTH_M, MU, OUTPUTS, R_M, Run, Settings,  # noqa: E402
                                     group_routing, multisine, row, save, simulate_plant, sine)

E_PA = 210e9             #: footnote 1: Young's modulus of the cable [Pa]
AREA_M2 = 3.14e-6        #: footnote 1: cable cross-section [m^2]


def footnote_stiffness_Nm_rad(r_m: float, E_Pa: float = E_PA, area_m2: float = AREA_M2,
                              length_m: float = LENGTH_M) -> float:
    """Footnote 1: ``K_q,1 = E A r^2 / L`` per cable, two identical cables in series -> ``K_q,1 / 2`` [Nm/rad]."""
    k1 = E_Pa * area_m2 * r_m ** 2 / length_m
    return k1 * k1 / (k1 + k1)


def effective_stiffness_Nm_rad(run: Run, frac: float = 0.6) -> float:
    """Slope of tau_in on (q_in - q_out) on the loading branches where ``|tau_in| > frac * max|tau_in|`` [Nm/rad]."""
    d = run.q_in_rad - run.q_out_rad
    tau_s = np.convolve(run.tau_in_Nm, np.ones(11) / 11.0, mode="same")
    loading = run.tau_in_Nm * np.gradient(tau_s) > 0.0
    sel = loading & (np.abs(run.tau_in_Nm) > frac * np.max(np.abs(run.tau_in_Nm)))
    A = np.column_stack([d[sel], np.ones(int(sel.sum()))])
    return float(np.linalg.lstsq(A, run.tau_in_Nm[sel], rcond=None)[0][0])


def hysteresis_height_Nm(run: Run, skip_s: float, smooth_s: float = 0.02) -> float:
    """Mean tau_out at falling minus at rising zero crossings of tau_in after ``skip_s`` [Nm].

    Both torques are smoothed over ``smooth_s`` [s] (a fixed time, so the estimate does not
    depend on the sample rate; the loop turns sharply at the reversals and a longer window
    cuts into it) and tau_out is interpolated linearly at each crossing.
    """
    dt = float(np.median(np.diff(run.t_s)))
    w = max(1, int(round(smooth_s / dt))) | 1
    k = np.ones(w) / w
    u = np.convolve(run.tau_in_Nm, k, mode="same")
    y = np.convolve(run.tau_out_Nm, k, mode="same")
    i0 = int(np.searchsorted(run.t_s, skip_s))
    h = w // 2
    up, down = [], []
    for i in range(max(i0, h + 1), len(u) - h):
        if (u[i - 1] < 0.0 <= u[i]) or (u[i - 1] > 0.0 >= u[i]):
            f = u[i - 1] / (u[i - 1] - u[i])
            (up if u[i] > u[i - 1] else down).append(y[i - 1] + f * (y[i] - y[i - 1]))
    if not up or not down:
        return math.nan
    return float(np.mean(down) - np.mean(up))


def transmission_slopes(run: Run, frac: float = 0.2) -> tuple[float, float]:
    """(pull, push) slopes of the upper cable's T_out on T_in while sliding (see module doc)."""
    v = run.dq_out_rad_s
    vmax = float(np.max(np.abs(v)))
    t_in, t_out = run.fixture_N[:, 0], run.fixture_N[:, 1]
    out = []
    for sel in (v > frac * vmax, v < -frac * vmax):
        out.append(float(np.dot(t_in[sel], t_out[sel]) / np.dot(t_in[sel], t_in[sel])) if sel.any() else math.nan)
    return out[0], out[1]


def tau_fc_Nm(routing_theta_rad: float, T0_eq_N: float) -> float:
    """Eq (19): ``mu theta T0_eq r`` [Nm]."""
    return MU * routing_theta_rad * T0_eq_N * R_M


def fig6(settings: Settings, out_dir: Path) -> dict[str, Any]:
    """Effective stiffness under sine and multisine excitation, varied transmission factors."""
    t0 = time.perf_counter()
    dur = 10.0 if settings.quick else 20.0
    cases = [("sine", 4, 150.0), ("multisine", 4, 150.0), ("sine", 7, 150.0), ("multisine", 8, 200.0),
             ("sine", 0, 200.0)]
    if settings.quick:
        cases = cases[:2] + cases[4:]
    rows, data = [], []
    fig, axes = plt.subplots(1, len(cases), figsize=(3.6 * len(cases), 3.4))
    for ax, (kind, j, T0) in zip(np.atleast_1d(axes), cases):
        r = group_routing(j)
        exc = sine(9.0, 0.2) if kind == "sine" else multisine(9.0)
        run = simulate_plant(r, exc, settings, OUTPUTS["stiff"], pretension_N=T0, effects=True, duration_s=dur)
        k = effective_stiffness_Nm_rad(run)
        band = 2.0 * tau_fc_Nm(r.theta_total_rad, pretension_field(r, MU, T0, T0).T0_eq_N)
        peak = float(np.max(np.abs(run.tau_in_Nm)))
        data.append({"excitation": kind, "theta_rad": r.theta_total_rad, "T0_N": T0, "K_eff_Nm_rad": k,
                     "peak_over_stick_band": peak / band})
        note = (f"peak/2tau_fc = {peak / band:.1f}, {100.0 * (k / K_C_NM_RAD - 1.0):+.0f} % vs K_c: near a reversal "
                "only part of each cable engages (steeper slope, paper Fig. 8 b); the excess shrinks as the "
                "peak grows past the stick band. Our plant is configured with K_c = 240 Nm/rad, so this row "
                "checks the stiffness estimate on the plant, it does not find the paper's value independently")
        rows.append(row(f"K_eff, {kind}, theta={r.theta_total_rad:.1f} rad, T0={T0:.0f} N", 240.0, k, "Nm/rad", note))
        d = run.q_in_rad - run.q_out_rad
        ax.plot(d * 1e3, run.tau_in_Nm, lw=0.5)
        dd = np.linspace(d.min(), d.max(), 2)
        ax.plot(dd * 1e3, K_C_NM_RAD * dd, "k--", lw=0.8, label="240 Nm/rad")
        ax.set_title(f"{kind}, θ={r.theta_total_rad:.1f}, T0={T0:.0f} N\nK_eff={k:.0f} Nm/rad", fontsize=9)
        ax.set_xlabel("q_in − q_out [mrad]")
        ax.set_ylabel("τ_in [Nm]")
        ax.legend(fontsize=7)
    png = save(fig, out_dir, "fig6_stiffness.png")
    kq_1mm = footnote_stiffness_Nm_rad(1e-3)
    kq_40mm = footnote_stiffness_Nm_rad(R_M)
    rows.append(row("footnote K_q, r = 1 mm (as printed)", 382.0, kq_1mm, "Nm/rad",
                    "E A r^2/L per cable, two in series: r = 1 mm gives 0.24 Nm/rad; the paper's 382 "
                    "follows with the pulley radius r = 40 mm"))
    rows.append(row("footnote K_q, r = 40 mm", 382.0, kq_40mm, "Nm/rad", "matches the paper's nominal value"))
    return {"title": "Fig. 6: effective torsional stiffness", "rows": rows, "figures": [png],
            "data": {"cases": data, "K_q_r1mm_Nm_rad": kq_1mm, "K_q_r40mm_Nm_rad": kq_40mm},
            "wall_s": time.perf_counter() - t0}


def _loop_ax(ax: Any, run: Run, label: str) -> None:
    ax.plot(run.tau_in_Nm, run.tau_out_Nm, lw=0.5, label=label)


def fig7(settings: Settings, out_dir: Path) -> dict[str, Any]:
    """Hysteresis vs pretension, bending and output dynamics; tension-transmission slopes."""
    t0 = time.perf_counter()
    dur, skip = 11.0, 4.0                          # two periods of 0.2 Hz after the fade-in
    pre_list = (80.0, 120.0, 160.0, 220.0) if settings.quick else (80.0, 120.0, 160.0, 200.0, 220.0)
    grp_list = (0, 4, 8) if settings.quick else (0, 2, 4, 6, 8)
    rows: list[dict[str, Any]] = []
    data: dict[str, Any] = {"pretension": [], "bending": [], "output": []}
    fig, axes = plt.subplots(2, 3, figsize=(12, 7))
    # (a) pretension sweep on theta_7 (1.9 rad), 5 Nm sine (slack-free at 80 N)
    r7 = group_routing(6)
    for T0 in pre_list:
        run = simulate_plant(r7, sine(5.0, 0.2), settings, OUTPUTS["stiff"], pretension_N=T0, duration_s=dur)
        h = hysteresis_height_Nm(run, skip)
        fc = tau_fc_Nm(r7.theta_total_rad, pretension_field(r7, MU, T0, T0).T0_eq_N)
        pull, push = transmission_slopes(run)
        data["pretension"].append({"T0_N": T0, "height_Nm": h, "two_tau_fc_Nm": 2 * fc, "pull": pull, "push": push})
        _loop_ax(axes[0, 0], run, f"T0={T0:.0f} N")
        axes[0, 2].plot([T0], [pull], "bv")
        axes[0, 2].plot([T0], [push], "r^")
    e = math.exp(MU * r7.theta_total_rad)
    axes[0, 2].axhline(1 / e, color="b", ls="--", lw=0.8, label="e^{-μθ}")
    axes[0, 2].axhline(e, color="r", ls="--", lw=0.8, label="e^{+μθ}")
    axes[0, 2].set(xlabel="pretension T0 [N]", ylabel="T_out/T_in slope", title=f"(c) slopes, θ={r7.theta_total_rad:.1f}")
    axes[0, 2].legend(fontsize=7)
    hs = [d["height_Nm"] for d in data["pretension"]]
    lo, hi = data["pretension"][0], data["pretension"][-1]
    rows.append(row(f"height ratio T0 {hi['T0_N']:.0f} N / {lo['T0_N']:.0f} N", None, hi["height_Nm"] / lo["height_Nm"], "-",
                    f"eq 19 predicts {hi['two_tau_fc_Nm'] / lo['two_tau_fc_Nm']:.2f} (friction proportional to pretension); "
                    "the paper shows the trend (Fig. 7 a/b) without numbers"))
    for d in data["pretension"]:
        rows.append(row(f"height, T0={d['T0_N']:.0f} N, θ={r7.theta_total_rad:.1f}", None, d["height_Nm"], "Nm",
                        f"eq 19: 2 tau_fc = {d['two_tau_fc_Nm']:.2f} Nm"))
    # (b) bending sweep at 150 N, 8 Nm sine
    for j in grp_list:
        r = group_routing(j)
        run = simulate_plant(r, sine(8.0, 0.2), settings, OUTPUTS["stiff"], duration_s=dur)
        h = hysteresis_height_Nm(run, skip)
        pf = pretension_field(r, MU, settings.pretension_N, settings.pretension_N)
        fc = tau_fc_Nm(r.theta_total_rad, pf.T0_eq_N)
        fc_fric = tau_fc_Nm(r.theta_total_rad, pf.T0_eq_friction_N)
        pull, push = transmission_slopes(run)
        th = r.theta_total_rad
        data["bending"].append({"theta_rad": th, "height_Nm": h, "two_tau_fc_Nm": 2 * fc,
                                "two_tau_fc_friction_Nm": 2 * fc_fric, "pull": pull, "push": push,
                                "exp_minus": math.exp(-MU * th), "exp_plus": math.exp(MU * th)})
        _loop_ax(axes[1, 0], run, f"θ={th:.1f}")
        rows.append(row(f"height, θ={th:.1f} rad, T0={settings.pretension_N:.0f} N", None, h, "Nm",
                        f"eq 19: 2 tau_fc = {2 * fc_fric:.2f} Nm with eq 25 friction-preserving, {2 * fc:.2f} Nm "
                        "at the field minimum (the plant has no unmodelled effects here: the loop height is its "
                        "sliding friction plus the partial-engagement stiffening near reversals)",
                        rid=f"7-height-{j + 1}"))
        rows.append(row(f"pull slope θ={th:.1f}", math.exp(-MU * th), pull, "-", "theory e^{-mu theta}"))
        rows.append(row(f"push slope θ={th:.1f}", math.exp(MU * th), push, "-", "theory e^{+mu theta}"))
    ths = np.array([d["theta_rad"] for d in data["bending"]])
    thg = np.linspace(0, ths.max() * 1.05, 50)
    axes[1, 2].plot(ths, [d["pull"] for d in data["bending"]], "bv", label="pull (fit)")
    axes[1, 2].plot(ths, [d["push"] for d in data["bending"]], "r^", label="push (fit)")
    axes[1, 2].plot(thg, np.exp(-MU * thg), "b--", lw=0.8, label="e^{-μθ}")
    axes[1, 2].plot(thg, np.exp(MU * thg), "r--", lw=0.8, label="e^{+μθ}")
    axes[1, 2].set(xlabel="θ [rad]", ylabel="T_out/T_in slope", title="(f) slopes vs bending")
    axes[1, 2].legend(fontsize=7)
    # (g/h) stiffness- vs damping-dominated output on theta_5
    r5 = group_routing(4)
    for name, outp in OUTPUTS.items():
        run = simulate_plant(r5, sine(8.0, 0.2), settings, outp, duration_s=dur)
        h = hysteresis_height_Nm(run, skip)
        data["output"].append({"output": name, "k_out": outp[0], "b_out": outp[1], "height_Nm": h})
        _loop_ax(axes[0, 1], run, f"{name}: k={outp[0]:g}, b={outp[1]:g}")
        rows.append(row(f"height, {name} output, θ={r5.theta_total_rad:.1f}", None, h, "Nm",
                        "damped output relaxes while the transmission sticks, so the loop is thinner and rounder"
                        if name == "damped" else "spring output holds its torque while sticking (play operator)"))
    for ax, title in ((axes[0, 0], "(a/b) pretension"), (axes[1, 0], "(d/e) bending"), (axes[0, 1], "(g/h) output dynamics")):
        ax.set(xlabel="τ_in [Nm]", ylabel="τ_out [Nm]", title=title)
        ax.legend(fontsize=7)
    axes[1, 1].plot([d["T0_N"] for d in data["pretension"]], hs, "o-", label=f"ours θ={r7.theta_total_rad:.1f}")
    axes[1, 1].plot([d["T0_N"] for d in data["pretension"]], [d["two_tau_fc_Nm"] for d in data["pretension"]], "k--",
                    label="eq 19: 2τ_fc")
    axes[1, 1].set(xlabel="pretension T0 [N]", ylabel="hysteresis height [Nm]", title="height vs pretension")
    axes[1, 1].legend(fontsize=7)
    png = save(fig, out_dir, "fig7_hysteresis.png")
    return {"title": "Fig. 7: hysteresis vs pretension, bending, output; tension transmission",
            "rows": rows, "figures": [png], "data": data, "wall_s": time.perf_counter() - t0}
