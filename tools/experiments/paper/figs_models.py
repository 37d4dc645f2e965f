"""Paper Fig. 11 on the simulated rig: the reduced model (this work) vs the single-sided model
(the authors' previous work) vs the Wu mapping, identified on theta_5 and used on every group.

Identification (the paper's protocol, made robust): on the reference run at theta_5 with the
stiffness-dominated output, multi-start least squares
(:func:`capstan.models.transmission.multistart.fit_multistart`, ``settings.n_starts`` starts)

* reduced model (eq 20/21): ``tau_fc``, ``zeta_s``, ``eta_s`` and the tanh steepness ``alpha``
  fitted; ``gamma`` held at :data:`GAMMA_NMS_RAD`, a regularising value 30x below the stiff
  output's damping (fitted freely it grew to 0.4-0.7 Nm s/rad, a real damper larger than
  ``b_out``, which the paper's "numerical regularisation" is not). The friction coefficient
  follows as ``mu = tau_fc / (theta_5 T0_eq,5 r)`` and the other groups use eq 19 with their own
  theta and T0_eq - in each reading of eq 25 (two rows, same fit);
* single-sided model: the friction-preserving reading's identified mu with its one-sided
  averaged pretension;
* Wu mapping: gain and threshold fitted independently; on other groups its constant-curvature
  form scales the threshold with theta.

Everything is repeated on every noise seed and on both plants (``effects``, ``imbalanced``);
rows give the mean over seeds and the spread. Panels (c) theta_1 stiff and (d) theta_2 damped
are the paper's single cases (:data:`~capstan.tools.experiments.paper.paper_values.PAPER_FIG11`);
the group means of panels (a)/(b) have no printed paper number.
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

from capstan.models.common.errors import ModelError  # noqa: E402
from capstan.models.transmission.baselines import GatedTransmission, single_sided_model  # noqa: E402
from capstan.models.transmission.multistart import fit_multistart  # noqa: E402
from capstan.models.transmission.pretension import Eq25Reading, pretension_field  # noqa: E402
from capstan.models.transmission.reduced import ReducedModel  # noqa: E402
from capstan.tools.experiments.paper.common import (GROUP_THETA_RAD, MU, OUTPUTS, PLANTS, R_M, Run, Settings,  # noqa: E402
                                                    claim, group_routing, rmse, row, save, spread_of)
from capstan.tools.experiments.paper.paper_values import PAPER_FIG11  # noqa: E402
from capstan.tools.experiments.paper.run_cache import PEAK_NM, RunCache  # noqa: E402

REF_GROUP = 4                    #: theta_5, the identification group (0-based)
GAMMA_NMS_RAD = 0.01             #: regularising gamma of eq 20, held fixed [Nm s/rad]
MODELS = ("reduced_friction_preserving", "reduced_field_minimum", "single_sided", "wu")
LABEL = {"reduced_friction_preserving": "this work (reduced), eq 25 friction-preserving",
         "reduced_field_minimum": "this work (reduced), eq 25 at the field minimum",
         "single_sided": "previous (single-sided)", "wu": "Wu"}
PAPER_KEY = {"reduced_friction_preserving": "reduced", "reduced_field_minimum": "reduced",
             "single_sided": "single_sided", "wu": "wu"}
RED_NAMES = ("tau_fc_Nm", "stribeck.zeta_s", "stribeck.eta_s_rad_s", "stribeck.alpha_s_rad")
RED_BOUNDS = ((0.05, 1.0, 1e-3, 5.0), (20.0, 3.0, 1.0, 1000.0))
#: Wu bounds: a threshold above the input's peak never lets the output move (no gradient there)
WU_BOUNDS = ((0.5, 0.0), (1.5, PEAK_NM))


def _t0_eq(j: int, mu: float, T0: float, reading: Eq25Reading) -> float:
    return pretension_field(group_routing(j), mu, T0, T0).T0_eq(reading)


def identify(run: Run, settings: Settings, seed: int) -> dict[str, Any]:
    """Multi-start fits of the reduced model and the Wu mapping on the theta_5 reference run.

    :raises ModelError: if no start gives a finite fit.
    """
    r = group_routing(REF_GROUP)
    T0 = settings.pretension_N
    k, b = OUTPUTS["stiff"]
    th5 = r.theta_total_rad
    red0 = ReducedModel.from_pretension(_t0_eq(REF_GROUP, MU, T0, Eq25Reading.FRICTION_PRESERVING), MU, th5, R_M,
                                        gamma_Nms_rad=GAMMA_NMS_RAD, k_out_Nm_rad=k, b_out_Nms_rad=b)
    red = fit_multistart(red0, RED_NAMES, run.t_s, run.tau_in_Nm, run.tau_out_Nm, RED_BOUNDS[0], RED_BOUNDS[1],
                         n_starts=settings.n_starts, seed=seed)
    wu0 = GatedTransmission(1.0, 2.0 * MU * th5 * T0 * R_M, k, b)
    wu = fit_multistart(wu0, ("gain", "threshold_Nm"), run.t_s, run.tau_in_Nm, run.tau_out_Nm, WU_BOUNDS[0],
                        WU_BOUNDS[1], n_starts=settings.n_starts, seed=seed)
    mu = {rd.name.lower(): red.model.tau_fc_Nm / (th5 * _t0_eq(REF_GROUP, MU, T0, rd) * R_M) for rd in Eq25Reading}
    return {"reduced": red, "wu": wu, "mu": mu, "theta_ref_rad": th5, "mu_plant": run.meta["mu_effective"]}


def predictors(ident: dict[str, Any], j: int, output: str, T0: float) -> dict[str, Any]:
    """The four predictors of group ``j`` (0-based) with the named output, from one identification."""
    th = group_routing(j).theta_total_rad
    k, b = OUTPUTS[output]
    red: ReducedModel = ident["reduced"].model
    wu: GatedTransmission = ident["wu"].model
    out: dict[str, Any] = {}
    for rd in Eq25Reading:
        mu = ident["mu"][rd.name.lower()]
        out[f"reduced_{rd.name.lower()}"] = ReducedModel(mu * th * _t0_eq(j, mu, T0, rd) * R_M, red.stribeck,
                                                         red.gamma_Nms_rad, k, b)
    out["single_sided"] = single_sided_model(group_routing(j), ident["mu"]["friction_preserving"], T0, R_M,
                                             k_out_Nm_rad=k, b_out_Nms_rad=b)
    out["wu"] = GatedTransmission(wu.gain, wu.threshold_Nm * th / ident["theta_ref_rad"], k, b)
    return out


def _evaluate(settings: Settings, cache: RunCache) -> tuple[dict[str, Any], dict[str, Any]]:
    """RMSE[plant][output][model] = (seeds x groups), and the identifications per plant and seed."""
    groups = settings.groups
    res: dict[str, Any] = {}
    idents: dict[str, Any] = {}
    for plant in PLANTS:
        res[plant] = {o: {m: np.full((len(settings.seeds), len(groups)), np.nan) for m in MODELS} for o in OUTPUTS}
        idents[plant] = []
        for si, seed in enumerate(settings.seeds):
            ident = identify(cache.get(REF_GROUP, "stiff", plant, seed), settings, seed)
            idents[plant].append(ident)
            for o in OUTPUTS:
                for gi, j in enumerate(groups):
                    run = cache.get(j, o, plant, seed)
                    for m, pred in predictors(ident, j, o, settings.pretension_N).items():
                        try:
                            res[plant][o][m][si, gi] = rmse(pred.predict_tau_out(run.t_s, run.tau_in_Nm),
                                                            run.tau_out_Nm)
                        except ModelError:
                            res[plant][o][m][si, gi] = math.nan
    return res, idents


def _rows(settings: Settings, res: dict[str, Any], idents: dict[str, Any]) -> tuple[list[Any], list[Any]]:
    groups = settings.groups
    rows: list[dict[str, Any]] = []
    claims: list[dict[str, Any]] = []
    for plant in PLANTS:
        tag, sfx = ("", "") if plant == "effects" else (" [imbalanced plant]", "-imb")
        for panel, (j, o, paper) in PAPER_FIG11.items():
            if j not in groups:
                continue
            gi = groups.index(j)
            for m in MODELS:
                v = res[plant][o][m][:, gi]
                rows.append(row(f"Fig. 11 ({panel}) θ{j + 1}={GROUP_THETA_RAD[j]:.1f} rad, {o} output, {LABEL[m]}{tag}",
                                paper[PAPER_KEY[m]], float(np.mean(v)), "Nm", _note(m, plant),
                                spread=spread_of(v), rid=f"11{panel}-{m[:10]}{sfx}"))
            r = {m: res[plant][o][m][:, gi] for m in MODELS}
            for m in ("reduced_friction_preserving", "reduced_field_minimum"):
                for other, pv in (("wu", paper["wu"]), ("single_sided", paper["single_sided"])):
                    claims.append(claim(f"Fig. 11 ({panel}) θ{j + 1} {o}: this work below {LABEL[other]} "
                                        f"({paper['reduced']:.4f} vs {pv:.4f} Nm), reading: "
                                        f"{m[8:].replace('_', ' ')}", list(r[m] < r[other]),
                                        [f"11{panel}-{m[:10]}{sfx}", f"11{panel}-{other[:10]}{sfx}"],
                                        f"{LABEL[m]} below {LABEL[other]}", plant))
        for o in OUTPUTS:
            for m in MODELS:
                v = res[plant][o][m]
                per_seed = np.nanmean(v, axis=1)
                rows.append(row(f"Fig. 11 ({'a' if o == 'stiff' else 'b'}) {o} output, {LABEL[m]}: mean RMSE over "
                                f"groups (range {np.nanmin(v):.3f}-{np.nanmax(v):.3f}){tag}", None,
                                float(np.mean(per_seed)), "Nm",
                                "the paper plots panels (a)/(b) without printed numbers: no like-for-like value",
                                spread=spread_of(per_seed), rid=f"11{'a' if o == 'stiff' else 'b'}-{m[:10]}{sfx}"))
        for m in MODELS:
            st, dm = np.nanmean(res[plant]["stiff"][m], axis=1), np.nanmean(res[plant]["damped"][m], axis=1)
            claims.append(claim(f"Fig. 11 (a)/(b): under the damping-dominated output the error increases "
                                f"({LABEL[m]})", list(dm > st), [f"11a-{m[:10]}{sfx}", f"11b-{m[:10]}{sfx}"],
                                "mean over groups damped above stiff", plant))
        rows += _ident_rows(idents[plant], tag, sfx)
    return rows, claims


def _ident_rows(idents: list[dict[str, Any]], tag: str, sfx: str) -> list[dict[str, Any]]:
    rows = []
    for rd in Eq25Reading:
        mus = [i["mu"][rd.name.lower()] for i in idents]
        rel = [i["mu"][rd.name.lower()] / i["mu_plant"] - 1.0 for i in idents]
        rows.append(row(f"identified μ on θ5, eq 25 {rd.name.lower().replace('_', ' ')}{tag}", MU,
                        float(np.mean(mus)), "-",
                        "the paper fixes μ = 0.052 from its earlier identification; our plant is configured "
                        "with 0.052 and carries a 20 % node-friction spread, whose normal-force-weighted mean "
                        "on θ5 is μ = " + ", ".join(f"{i['mu_plant']:.4f}" for i in idents) + " on the seeds: "
                        "identified − plant = " + ", ".join(f"{100 * x:+.1f} %" for x in rel),
                        spread=spread_of(mus), rid=f"11-mu-{rd.name.lower()[:4]}{sfx}"))
    for name, key in (("reduced", "reduced"), ("Wu", "wu")):
        fits = [i[key] for i in idents]
        best = [f.rmse_Nm for f in fits]
        worst = max(float(np.nanmax(f.rmse_starts_Nm)) for f in fits)
        ranges = [f.parameter_ranges() for f in fits]
        par = "; ".join(f"{n.split('.')[-1]} {min(r[n][0] for r in ranges):.4g}-{max(r[n][1] for r in ranges):.4g}"
                        for n in fits[0].names)
        rows.append(row(f"{name} fit on θ5: best-start RMSE{tag}", None, float(np.mean(best)), "Nm",
                        f"{fits[0].rmse_starts_Nm.size} starts per seed, the worst start ended at {worst:.3f} Nm; "
                        f"near-best starts (within {100 * fits[0].near:.0f} %): "
                        f"{', '.join(str(int(f.near_best.sum())) for f in fits)} per seed, their parameters {par}"
                        + (f"; γ held at {GAMMA_NMS_RAD} Nm s/rad (regularising)" if key == "reduced" else ""),
                        spread=spread_of(best), rid=f"11-fit-{key}{sfx}"))
    return rows


def _note(model: str, plant: str) -> str:
    base = ("simulated plant: lacks most of the real rig's unmodelled effects, so every model is far below the "
            "paper's RMSE" if plant == "effects" else
            "plant of another structure (opposite along-cable imbalance the models cannot see)")
    if model == "reduced_field_minimum":
        return base + "; every spring at the field minimum under-states tau_fc on bent groups relative to θ5"
    if model == "single_sided":
        return base + "; the one-sided field over-weights the input-side pretension, gating adds abrupt transitions"
    if model == "wu":
        return base + "; a threshold on a linear output is the plant's own structure, scaled with θ only"
    return base


def fig11(settings: Settings, out_dir: Path, cache: RunCache) -> dict[str, Any]:
    """Four models x groups x outputs x seeds x plants; rows per paper panel and case, claims checked."""
    t0 = time.perf_counter()
    res, idents = _evaluate(settings, cache)
    rows, claims = _rows(settings, res, idents)
    th = [GROUP_THETA_RAD[j] for j in settings.groups]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2), sharey=True)
    for ax, o in zip(axes, OUTPUTS):
        for m, mk in zip(MODELS, ("o-", "o--", "s-", "^-")):
            v = res["effects"][o][m]
            mean = np.nanmean(v, axis=0)
            ax.errorbar(th, mean, yerr=[mean - np.nanmin(v, axis=0), np.nanmax(v, axis=0) - mean], fmt=mk,
                        capsize=2, label=LABEL[m])
        ax.set(xlabel="θ [rad] (group)", ylabel="RMSE [Nm]",
               title=f"{o} output (k={OUTPUTS[o][0]:g}, b={OUTPUTS[o][1]:g}); bars: seeds")
        ax.invert_xaxis()
        ax.legend(fontsize=7)
    pngs = [save(fig, out_dir, "fig11_models.png")]
    eff = idents["effects"][0]
    return {"title": "Fig. 11: reduced (both eq 25 readings) vs single-sided vs Wu, identified on θ5",
            "rows": rows, "claims": claims, "figures": pngs,
            "data": {"groups": [int(j) for j in settings.groups], "theta_rad": th, "seeds": list(settings.seeds),
                     "mu_plant_theta5": {p: [i["mu_plant"] for i in lst] for p, lst in idents.items()},
                     "rmse_Nm": {o: {m: np.nanmean(v, axis=0).tolist() for m, v in d.items()}
                                 for o, d in res["effects"].items()},
                     "rmse_by_plant_seed_Nm": {p: {o: {m: v.tolist() for m, v in d.items()} for o, d in dp.items()}
                                               for p, dp in res.items()},
                     "identified": {p: [{"mu": i["mu"], "mu_plant": i["mu_plant"], "reduced_fit": i["reduced"].summary(),
                                         "wu_fit": i["wu"].summary()} for i in lst] for p, lst in idents.items()},
                     "gamma_Nms_rad": GAMMA_NMS_RAD, "first_identification_effects": eff["reduced"].summary()},
            "wall_s": time.perf_counter() - t0}
