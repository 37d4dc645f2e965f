"""Paper Figs. 9-11 on the simulated rig: prediction RMSE of the distributed model for
N = 1 ... 20 with the distributed (eq 23) and the averaged (eq 25) pretension across the ten
routing groups, and the reduced model vs the single-sided model vs the Wu mapping.

Protocol (the paper's, on measured runs of the ground-truth plant, see
:mod:`capstan.tools.experiments.paper.common`): every model is driven by the measured input torque and
predicts the testbed output torque; RMSE against the measured output torque [Nm]. The
distributed predictions use the specification (routing, nominal pretension, mu = 0.052).
For Fig. 11 the free parameters are identified on one reference run at theta_5 (stiffness
output) and then used on every group and both output dynamics:

* reduced model (eq 20/21): ``tau_fc``, ``zeta_s``, ``eta_s``, ``gamma`` fitted; the friction
  coefficient follows as ``mu = tau_fc / (theta_5 T0_eq,5 r)`` and the other groups use
  eq 19 with their own theta and T0_eq (eq 25);
* single-sided model: the same identified mu with its one-sided averaged pretension;
* Wu mapping: gain and threshold fitted independently by least squares; on other groups its
  constant-curvature form scales the threshold with theta (``2 mu theta T0 r``).
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

from capstan.models.transmission.baselines import GatedTransmission, fit_parameters, single_sided_model  # noqa: E402
from capstan.models.common.errors import ModelError  # noqa: E402
from capstan.models.transmission.pretension import pretension_field, segment_tensions_N  # noqa: E402
from capstan.models.transmission.reduced import ReducedModel  # noqa: E402
from capstan.tools.experiments.paper.common import (GROUP_THETA_RAD, MU, OUTPUTS, R_M, Run, Settings, group_routing,  # noqa: E402
                                     multisine, predict_distributed, rmse, row, save, simulate_plant, sine)

#: paper Fig. 9 RMSE [Nm]: (case, pretension) -> (N = 1, N = 10)
PAPER_FIG9 = {("bent", "distributed"): (1.2132, 0.3839), ("flat", "distributed"): (0.5108, 0.4101),
              ("bent", "averaged"): (0.4406, 0.5699), ("flat", "averaged"): (0.3989, 0.3944)}
#: paper Fig. 11 RMSE ranges [Nm] over the groups (this work, previous single-sided, Wu)
PAPER_FIG11 = {"reduced": (0.34, 0.44), "single_sided": (0.75, 0.96), "wu": (1.12, 1.15)}
PEAK_NM = 8.0


class RunCache:
    """Measured runs shared by the figures, keyed by (group, output, effects)."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self._runs: dict[tuple[int, str, bool], Run] = {}

    def get(self, j: int, output: str, effects: bool = True) -> Run:
        """Multisine measured run of group ``j`` (0-based) with the named output.

        :raises OperatingRangeError: on cable slack. :raises IntegrationError: on solver failure.
        """
        key = (j, output, effects)
        if key not in self._runs:
            self._runs[key] = simulate_plant(group_routing(j), multisine(PEAK_NM), self.settings, OUTPUTS[output],
                                             effects=effects, seed_offset=j)
        return self._runs[key]


def fig9_10(settings: Settings, out_dir: Path, cache: RunCache) -> dict[str, Any]:
    """RMSE over groups x N for the distributed and the averaged pretension (+ the two Fig. 9 cases)."""
    t0 = time.perf_counter()
    T0 = settings.pretension_N
    groups, ns = settings.groups, settings.n_list
    grid = {m: np.full((len(groups), len(ns)), np.nan) for m in ("distributed", "averaged")}
    ideal = {m: np.full((len(groups), 2), np.nan) for m in ("distributed", "averaged")}
    for gi, j in enumerate(groups):
        r = group_routing(j)
        run = cache.get(j, "stiff", True)
        clean = cache.get(j, "stiff", False)
        for mode in grid:
            for ni, n in enumerate(ns):
                grid[mode][gi, ni] = rmse(predict_distributed(run, r, n, mode == "averaged", T0, OUTPUTS["stiff"]),
                                          run.tau_out_Nm)
            for k, n in enumerate((1, 10)):
                ideal[mode][gi, k] = rmse(predict_distributed(clean, r, n, mode == "averaged", T0, OUTPUTS["stiff"]),
                                          clean.tau_out_Nm)
    # the two demonstration cases of Fig. 9: bent theta_1 sine / stiff, flat theta_8 multisine / damped
    demo: dict[str, Any] = {}
    rows: list[dict[str, Any]] = []
    fig, axes = plt.subplots(2, 2, figsize=(12, 6.5), sharex=True)
    for ci, (case, j, exc, outp) in enumerate((("bent", 0, sine(PEAK_NM, 0.2), "stiff"),
                                               ("flat", 7, multisine(PEAK_NM), "damped"))):
        r = group_routing(j)
        run = simulate_plant(r, exc, settings, OUTPUTS[outp], effects=True, seed_offset=50 + j)
        for mi, mode in enumerate(("distributed", "averaged")):
            ax = axes[ci, mi]
            ax.plot(run.t_s, run.tau_out_Nm, "k", lw=0.8, label="measured")
            vals = []
            for n in (1, 10):
                p = predict_distributed(run, r, n, mode == "averaged", T0, OUTPUTS[outp])
                vals.append(rmse(p, run.tau_out_Nm))
                ax.plot(run.t_s, p, lw=0.7, label=f"N={n}: {vals[-1]:.3f} Nm")
            ax.set_title(f"{case} θ={r.theta_total_rad:.1f} ({outp}), {mode} pretension", fontsize=9)
            ax.set_ylabel("τ_out [Nm]")
            ax.legend(fontsize=7)
            demo[f"{case}_{mode}"] = vals
            for k, n in enumerate((1, 10)):
                paper = PAPER_FIG9[(case, mode)][k]
                rows.append(row(f"Fig. 9 {case} θ={r.theta_total_rad:.1f}, {mode}, N={n}", paper, vals[k], "Nm",
                                _fig9_note(case, mode, n)))
    for ax in axes[1]:
        ax.set_xlabel("t [s]")
    pngs = [save(fig, out_dir, "fig9_prediction.png")]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    vmax = max(float(np.nanmax(g)) for g in grid.values())
    for ax, (mode, g) in zip(axes, grid.items()):
        im = ax.imshow(g, aspect="auto", origin="upper", vmin=0.0, vmax=vmax, cmap="viridis")
        ax.set_xticks(range(len(ns)), [str(n) for n in ns], fontsize=7)
        ax.set_yticks(range(len(groups)), [f"θ{j + 1}={GROUP_THETA_RAD[j]:.1f}" for j in groups], fontsize=7)
        ax.set(xlabel="N (nodes per cable)", title=f"RMSE [Nm], {mode} pretension")
        fig.colorbar(im, ax=ax)
    pngs.append(save(fig, out_dir, "fig10_rmse_heatmap.png"))
    i10 = ns.index(10) if 10 in ns else len(ns) - 1
    for mode, g in grid.items():
        rows.append(row(f"Fig. 10 {mode}: RMSE range over groups, N={ns[0]}", None, float(np.nanmax(g[:, 0])), "Nm",
                        f"min {np.nanmin(g[:, 0]):.3f} Nm; with unmodelled effects in the plant"))
        rows.append(row(f"Fig. 10 {mode}: RMSE range over groups, N={ns[i10]}", None, float(np.nanmax(g[:, i10])), "Nm",
                        f"min {np.nanmin(g[:, i10]):.3f} Nm"))
        rows.append(row(f"ideal plant (no unmodelled effects), {mode}, N=10, worst group", None,
                        float(np.nanmax(ideal[mode][:, 1])), "Nm", "sensor noise only: the model at large N is the truth"))
    return {"title": "Figs. 9-10: prediction RMSE vs N and routing, distributed vs averaged pretension",
            "rows": rows, "figures": pngs,
            "data": {"groups": [int(j) for j in groups], "theta_rad": [GROUP_THETA_RAD[j] for j in groups],
                     "n_list": list(ns), "rmse_Nm": {m: g.tolist() for m, g in grid.items()},
                     "rmse_ideal_N1_N10_Nm": {m: g.tolist() for m, g in ideal.items()}, "fig9": demo},
            "wall_s": time.perf_counter() - t0}


def _fig9_note(case: str, mode: str, n: int) -> str:
    if mode == "distributed" and n == 1 and case == "bent":
        return ("ours far lower: our N = 1 springs sit at the fixture values of the eq 23 field (<= 8 % above its "
                "mean at mu theta = 0.31); the paper drove N = 1 with a different input than N = 10 and its "
                "floor contains unmodelled rig effects")
    if mode == "averaged":
        return ("eq 25 puts every spring at T(s_min), the field's minimum: friction is under-estimated by "
                "the field's excess over its minimum at every N, most on bent routings; lower than the paper's "
                "overall: the simulated plant lacks most of the real rig's unmodelled effects")
    return "simulated plant: the distributed model at large N is the truth up to the added effects"


def _identify(run: Run, j: int, settings: Settings) -> dict[str, Any]:
    """Fit the reduced model and the Wu mapping on the reference run of group ``j``."""
    r = group_routing(j)
    T0 = settings.pretension_N
    T0_eq = pretension_field(r, MU, T0, T0).T0_eq_N
    k, b = OUTPUTS["stiff"]
    red0 = ReducedModel.from_pretension(T0_eq, MU, r.theta_total_rad, R_M, k_out_Nm_rad=k, b_out_Nms_rad=b)
    red, red_rmse = fit_parameters(red0, ["tau_fc_Nm", "stribeck.zeta_s", "stribeck.eta_s_rad_s", "gamma_Nms_rad"],
                                   run.t_s, run.tau_in_Nm, run.tau_out_Nm, lower=[0.05, 1.0, 1e-3, 1e-4],
                                   upper=[20.0, 3.0, 1.0, 2.0])
    mu_id = red.tau_fc_Nm / (r.theta_total_rad * T0_eq * R_M)
    wu0 = GatedTransmission(1.0, 2.0 * MU * r.theta_total_rad * T0 * R_M, k, b)
    wu, wu_rmse = fit_parameters(wu0, ["gain", "threshold_Nm"], run.t_s, run.tau_in_Nm, run.tau_out_Nm,
                                 lower=[0.5, 0.0], upper=[1.5, 20.0])
    return {"reduced": red, "mu": mu_id, "wu": wu, "theta_ref_rad": r.theta_total_rad,
            "fit_rmse_Nm": {"reduced": red_rmse, "wu": wu_rmse}}


def _predictors(ident: dict[str, Any], j: int, output: str, T0: float) -> dict[str, Any]:
    r = group_routing(j)
    k, b = OUTPUTS[output]
    red: ReducedModel = ident["reduced"]
    T0_eq = pretension_field(r, ident["mu"], T0, T0).T0_eq_N
    wu: GatedTransmission = ident["wu"]
    return {
        "reduced": ReducedModel(ident["mu"] * r.theta_total_rad * T0_eq * R_M, red.stribeck, red.gamma_Nms_rad, k, b),
        "single_sided": single_sided_model(r, ident["mu"], T0, R_M, k_out_Nm_rad=k, b_out_Nms_rad=b),
        "wu": GatedTransmission(wu.gain, wu.threshold_Nm * r.theta_total_rad / ident["theta_ref_rad"], k, b),
    }


def fig11(settings: Settings, out_dir: Path, cache: RunCache) -> dict[str, Any]:
    """Reduced vs single-sided vs Wu across the groups, stiffness- and damping-dominated output."""
    t0 = time.perf_counter()
    ref_j = 4
    ident = _identify(cache.get(ref_j, "stiff", True), ref_j, settings)
    groups = settings.groups
    models = ("reduced", "single_sided", "wu")
    res = {o: {m: np.full(len(groups), np.nan) for m in models} for o in OUTPUTS}
    for o in OUTPUTS:
        for gi, j in enumerate(groups):
            run = cache.get(j, o, True)
            for m, pred in _predictors(ident, j, o, settings.pretension_N).items():
                try:
                    res[o][m][gi] = rmse(pred.predict_tau_out(run.t_s, run.tau_in_Nm), run.tau_out_Nm)
                except ModelError:
                    res[o][m][gi] = math.nan
    rows: list[dict[str, Any]] = []
    names = {"reduced": "this work (reduced)", "single_sided": "previous (single-sided)", "wu": "Wu"}
    for o in OUTPUTS:
        best = min(models, key=lambda m: float(np.nanmean(res[o][m])))
        for m in models:
            lo, hi = PAPER_FIG11[m]
            v = res[o][m]
            rows.append(row(f"Fig. 11 {o} output, {names[m]}: mean RMSE (range {np.nanmin(v):.3f}-{np.nanmax(v):.3f})",
                            0.5 * (lo + hi), float(np.nanmean(v)), "Nm",
                            _fig11_note(m, best, groups, v, ident, o, settings.pretension_N)))
    rows.append(row("identified mu (reduced model on θ5)", MU, ident["mu"], "-",
                    "the configured 0.052; the plant carries a 20 % node-friction spread and a pretension asymmetry"))
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2), sharey=True)
    th = [GROUP_THETA_RAD[j] for j in groups]
    for ax, o in zip(axes, OUTPUTS):
        for m, mk in zip(models, ("o-", "s-", "^-")):
            ax.plot(th, res[o][m], mk, label=names[m])
        ax.set(xlabel="θ [rad] (group)", ylabel="RMSE [Nm]", title=f"{o} output (k={OUTPUTS[o][0]:g}, b={OUTPUTS[o][1]:g})")
        ax.invert_xaxis()
        ax.legend(fontsize=7)
    pngs = [save(fig, out_dir, "fig11_models.png")]
    red = ident["reduced"]
    return {"title": "Fig. 11: reduced vs single-sided vs Wu (parameters identified on θ5)", "rows": rows,
            "figures": pngs,
            "data": {"groups": [int(j) for j in groups], "theta_rad": th,
                     "rmse_Nm": {o: {m: v.tolist() for m, v in d.items()} for o, d in res.items()},
                     "identified": {"mu": ident["mu"], "tau_fc_ref_Nm": red.tau_fc_Nm, "zeta_s": red.stribeck.zeta_s,
                                    "eta_s_rad_s": red.stribeck.eta_s_rad_s, "gamma_Nms_rad": red.gamma_Nms_rad,
                                    "wu_gain": ident["wu"].gain, "wu_threshold_ref_Nm": ident["wu"].threshold_Nm,
                                    "fit_rmse_Nm": ident["fit_rmse_Nm"]}},
            "wall_s": time.perf_counter() - t0}


def _fig11_note(model: str, best: str, groups: tuple[int, ...], rmse_Nm: np.ndarray, ident: dict[str, Any],
                output: str, T0_N: float) -> str:
    """Why ours differs from the paper's Fig. 11, with the numbers of this run."""
    common = "below the paper's: the simulated plant lacks most of the real rig's unmodelled effects"
    gi = int(np.nanargmax(rmse_Nm))
    j = groups[gi]
    if model == "reduced":
        def eq25_over_mean(jj: int) -> float:
            r = group_routing(jj)
            return (0.5 * pretension_field(r, ident["mu"], T0_N, T0_N).T0_eq_N
                    / float(np.mean(segment_tensions_N(r, ident["mu"], T0_N, T0_N, 200))))
        return (f"{common}; worst on θ{j + 1} = {GROUP_THETA_RAD[j]:.1f} rad ({rmse_Nm[gi]:.3f} Nm): eq 19 scales "
                f"tau_fc with theta T0_eq, and eq 25's T0_eq/2 is {eq25_over_mean(j):.3f} of the eq 23 field's mean "
                f"there vs {eq25_over_mean(4):.3f} on θ5 where tau_fc was identified")
    if model == "single_sided":
        return f"{common}; the one-sided field over-weights the input-side pretension, gating adds abrupt transitions"
    if best == "wu":
        j = min(groups)                                     # the most bent group evaluated
        r = group_routing(j)
        pred = _predictors(ident, j, output, T0_N)
        return (f"lowest of the three here, unlike the paper: our plant's friction is a threshold on a linear output "
                f"(Wu's structure) and its threshold, fitted on θ5 and scaled with theta at fixed pretension "
                f"(θ{j + 1} = {r.theta_total_rad:.1f} rad: {pred['wu'].threshold_Nm:.2f} Nm vs the reduced "
                f"model's tau_fc {pred['reduced'].tau_fc_Nm:.2f} Nm), follows the plant's friction; the paper "
                "blames Wu's errors on constant curvature and uniform pretension on its rig")
    return "constant curvature, uniform T0 and threshold gating; fitted only on θ5"
