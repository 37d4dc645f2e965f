"""What a rig engineer should configure, derived from the numbers of one paper-reproduction run
(:mod:`capstan.tools.experiments.paper.experiment`): the discretisation N and pretension model of the distributed
model per routing (Figs. 9-10), whether the reduced model suffices (Fig. 11), and the
friction-feedforward placement and controller per condition (Fig. 13).

Rules (no number here is taken from the paper; every one comes from the run's results):

* **N per routing group**: the smallest evaluated N whose RMSE on that group's measured run
  (distributed pretension field, eq 23) exceeds the largest evaluated N's by no more than
  ``max(tol * RMSE, sigma)``: ``tol`` = 10 %, ``sigma`` the torque sensor's noise standard
  deviation (a smaller difference cannot be told apart on the rig). N = 1 is excluded when it
  fails the same test against N = 10 on the group's ideal run (no unmodelled effects): on a
  measured run N = 1 can win only because its friction error cancels an unmodelled one.
  Groups are split into "bent" and "flat" at the middle of the evaluated bending range.
* **pretension model**: per evaluated N, which of the distributed (eq 23) and the averaged
  (eq 25, each reading) pretension has the lower mean RMSE over the groups.
* **reduced model**: its RMSE (parameters identified on theta_5) next to the distributed model
  at the recommended N, per group, on the same measured runs (stiffness-dominated output).
* **eq 25 reading** (the feedforward's default, ``controller.feedforward.eq25_reading``): the
  reading that wins more of three data tests: (1) Fig. 7's loop heights on the plant without
  unmodelled effects (sliding friction) against ``2 tau_fc`` of eq 19 with each reading (closer
  on more groups), (2) Fig. 10's mean RMSE of the averaged-pretension predictions over groups and
  N, (3) Fig. 11's mean RMSE of the reduced model over groups, both outputs.
* **feedforward placement**: per condition and feedforward controller, the placement (torque
  reference or motor command as eq 28 prints it) with the lower mean ``|tau_h|``; a run whose
  safety stage latched counts as worse than any run that did not.
"""

from __future__ import annotations

import math
from typing import Any

from capstan.models.plant.rig import SensorNoise
from capstan.tools.experiments.paper.common import MU

#: relative RMSE margin over the largest N within which a smaller N is "enough" [-]
N_TOLERANCE = 0.10


def recommend(figures: dict[str, Any], tol: float = N_TOLERANCE) -> dict[str, Any]:
    """Recommendation from the figure results present (keys ``fig9_10``, ``fig11``, ``fig13``).

    :returns: ``{"n": ..., "reduced_model": ..., "placement": ..., "text": [markdown lines]}``;
        parts whose figures were not run are absent, ``text`` is always present.
    """
    out: dict[str, Any] = {"tolerance": tol, "text": []}
    if "fig9_10" in figures:
        out["n"] = _n_choice(figures["fig9_10"]["data"], tol)
        out["text"] += out["n"]["text"]
        if "fig11" in figures:
            out["reduced_model"] = _reduced_vs_distributed(figures["fig11"]["data"], figures["fig9_10"]["data"],
                                                           out["n"])
            out["text"] += out["reduced_model"]["text"]
    if any(k in figures for k in ("fig7", "fig9_10", "fig11")):
        out["eq25"] = _eq25_choice(figures)
        out["text"] += out["eq25"]["text"]
    if "fig13" in figures:
        out["placement"] = _placement(figures["fig13"]["data"])
        out["text"] += out["placement"]["text"]
    if not out["text"]:
        out["text"].append("No recommendation: it needs Figs. 9-10, 11 or 13 in the run.")
    return out


def _finite(x: Any) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


def _close(v: Any, ref: float, tol: float) -> bool:
    """``v`` exceeds ``ref`` by no more than ``max(tol * ref, sigma_torque)``."""
    return _finite(v) and v <= ref + max(tol * ref, SensorNoise().torque_Nm)


def _n_min(ns: list[int], rmse: list[Any], tol: float, allow_n1: bool = True) -> int | None:
    """Smallest N whose RMSE is close (:func:`_close`) to the largest N's (None if that is missing)."""
    ref = rmse[-1]
    if not _finite(ref):
        return None
    for n, v in zip(ns, rmse):
        if (n > 1 or allow_n1) and _close(v, ref, tol):
            return int(n)
    return int(ns[-1])


def _n_choice(data: dict[str, Any], tol: float) -> dict[str, Any]:
    ns = [int(n) for n in data["n_list"]]
    thetas = [float(t) for t in data["theta_rad"]]
    dist = data["rmse_Nm"]["distributed"]
    avg_by = {k: v for k, v in data["rmse_Nm"].items() if k != "distributed"}
    avg = avg_by.get("friction_preserving", next(iter(avg_by.values())))
    split = 0.5 * (min(thetas) + max(thetas))
    per_group = []
    ideal = data["rmse_ideal_N1_N10_Nm"]["distributed"]
    for gi, (j, th) in enumerate(zip(data["groups"], thetas)):
        n1_ok = _close(ideal[gi][0], ideal[gi][1], tol) if _finite(ideal[gi][1]) else True
        n_d = _n_min(ns, dist[gi], tol, allow_n1=n1_ok)
        per_group.append({"group": int(j) + 1, "theta_rad": th, "bent": th > split, "n_min": n_d,
                          "n1_ok_ideal": n1_ok, "ideal_n1_n10_Nm": list(ideal[gi]),
                          "rmse_at_n_min_Nm": dist[gi][ns.index(n_d)] if n_d is not None else None,
                          "rmse_at_n_max_Nm": dist[gi][-1], "rmse_n1_distributed_Nm": dist[gi][0],
                          "rmse_n1_averaged_Nm": avg[gi][0]})
    by_class: dict[str, int | None] = {}
    for name, bent in (("bent", True), ("flat", False)):
        vals = [g["n_min"] for g in per_group if g["bent"] == bent and g["n_min"] is not None]
        by_class[name] = max(vals) if vals else None
    valid = [g["n_min"] for g in per_group if g["n_min"] is not None]
    overall = max(valid) if valid else None
    # pretension model per N: lower mean RMSE over the groups (averaged = eq 25, friction-preserving reading)
    pre = []
    for ni, n in enumerate(ns):
        md = _mean([row[ni] for row in dist])
        ma = _mean([row[ni] for row in avg])
        pre.append({"n": n, "distributed_mean_Nm": md, "averaged_mean_Nm": ma,
                    "averaged_by_reading_mean_Nm": {k: _mean([row[ni] for row in v]) for k, v in avg_by.items()},
                    "better": "distributed" if md <= ma else "averaged"})
    sigma = SensorNoise().torque_Nm
    excluded = [g for g in per_group if not g["n1_ok_ideal"]]
    text = [f"**Discretisation N** (smallest N whose RMSE on the group's measured run exceeds the N = {ns[-1]} "
            f"RMSE by at most max({100 * tol:.0f} %, σ = {sigma:g} Nm torque-sensor noise), distributed "
            f"pretension"
            + (f"; N = 1 excluded where it fails that test against N = 10 on the ideal plant: "
               + ", ".join(f"θ{g['group']} ({_fmt(g['ideal_n1_n10_Nm'][0])} vs {_fmt(g['ideal_n1_n10_Nm'][1])} Nm)"
                           for g in excluded) if excluded else "")
            + "): "
            + ", ".join(f"θ{g['group']} = {g['theta_rad']:.1f} rad → N = {g['n_min']}"
                        f" ({_fmt(g['rmse_at_n_min_Nm'])} vs {_fmt(g['rmse_at_n_max_Nm'])} Nm)" for g in per_group)
            + "."]
    text.append(f"Routing dependence: {_class_text(per_group, True, split)}; {_class_text(per_group, False, split)}; "
                f"one N for every routing: **N = {overall}** (paper, Fig. 10 on its rig: "
                "more than 4-5 segments, steeply bent groups worst at coarse N). "
                f"At μ = {MU:g} the eq 23 field dips at most {100 * (1 - math.exp(-MU * max(thetas) / 2)):.0f} % "
                f"below the boundary pretension (θ = {max(thetas):.1f} rad), so coarse N costs little here; "
                f"the largest spread over N on one group is "
                f"{_fmt(_largest_spread(dist))} Nm.")
    small, large = pre[0], pre[-1]

    def readings(p: dict[str, Any]) -> str:
        return ", ".join(f"{k.replace('_', ' ')} {_fmt(v)}" for k, v in p["averaged_by_reading_mean_Nm"].items())

    text.append(f"**Pretension model**: at N = {small['n']} the {small['better']} pretension predicts better "
                f"(mean RMSE {_fmt(small['distributed_mean_Nm'])} Nm distributed vs "
                f"{_fmt(small['averaged_mean_Nm'])} Nm averaged with eq 25 friction-preserving; eq 25 readings: "
                f"{readings(small)} Nm); at N = {large['n']} the {large['better']} "
                f"({_fmt(large['distributed_mean_Nm'])} vs {_fmt(large['averaged_mean_Nm'])} Nm; {readings(large)} Nm). "
                + _pretension_advice(pre))
    return {"tolerance": tol, "split_theta_rad": split, "per_group": per_group, "bent_n": by_class["bent"],
            "flat_n": by_class["flat"], "overall_n": overall, "pretension_by_n": pre, "text": text}


def _class_text(per_group: list[dict[str, Any]], bent: bool, split: float) -> str:
    """Which N the bent (or flat) groups need, naming the groups that need more than the others."""
    gs = [g for g in per_group if g["bent"] == bent and g["n_min"] is not None]
    what = f"bent routings (θ > {split:.1f} rad)" if bent else f"flat routings (θ ≤ {split:.1f} rad)"
    if not gs:
        return f"{what}: none evaluated"
    ns = sorted({g["n_min"] for g in gs})
    if len(ns) == 1:
        return f"{what} need N = {ns[0]}"
    top = max(ns)
    return (f"{what} need N = {ns[0]}-{top}: N = {top} only on "
            + ", ".join(f"θ{g['group']}" for g in gs if g["n_min"] == top)
            + ", N = " + "/".join(str(n) for n in ns[:-1]) + " on "
            + ", ".join(f"θ{g['group']}" for g in gs if g["n_min"] != top))


def _pretension_advice(pre: list[dict[str, Any]]) -> str:
    switch = next((p["n"] for p in pre if p["better"] == "distributed"), None)
    if switch is None:
        return "The averaged pretension (eq 25) is better at every evaluated N."
    if switch == pre[0]["n"]:
        return "The distributed field (eq 23) is better from the smallest evaluated N on."
    return f"Use eq 25 below N = {switch}, the eq 23 field from N = {switch} on."


def _reduced_vs_distributed(d11: dict[str, Any], d9: dict[str, Any], nchoice: dict[str, Any]) -> dict[str, Any]:
    red = d11["rmse_Nm"]["stiff"].get("reduced_friction_preserving", d11["rmse_Nm"]["stiff"].get("reduced"))
    rows = []
    for gi, j in enumerate(d11["groups"]):
        if j not in d9["groups"]:
            continue
        g = nchoice["per_group"][d9["groups"].index(j)]
        rows.append({"group": int(j) + 1, "theta_rad": g["theta_rad"], "reduced_Nm": red[gi],
                     "distributed_n": g["n_min"], "distributed_Nm": g["rmse_at_n_min_Nm"]})
    ok = [r for r in rows if _finite(r["reduced_Nm"]) and _finite(r["distributed_Nm"])]
    worst = max(ok, key=lambda r: r["reduced_Nm"] - r["distributed_Nm"]) if ok else None
    text = []
    if worst is not None:
        text.append("**Reduced model** (the feedforward's τ̂_fc with eq 25 friction-preserving, identified once on "
                    "θ5; mean over the seeds): RMSE "
                    + ", ".join(f"θ{r['group']} {_fmt(r['reduced_Nm'])} Nm (distributed N = {r['distributed_n']}: "
                                f"{_fmt(r['distributed_Nm'])})" for r in ok)
                    + f"; the largest gap is {_fmt(worst['reduced_Nm'] - worst['distributed_Nm'])} Nm at "
                      f"θ{worst['group']} = {worst['theta_rad']:.1f} rad.")
    return {"per_group": rows, "text": text}


def _eq25_choice(figures: dict[str, Any]) -> dict[str, Any]:
    """Which eq 25 reading the run's data support (see the module doc), with the numbers."""
    from capstan.controller.law.config import FeedforwardConfig

    votes: dict[str, int] = {"friction_preserving": 0, "field_minimum": 0}
    parts: list[str] = []
    if "fig7" in figures:
        bend = figures["fig7"]["data"].get("bending", [])
        closer = [abs(b["height_Nm"] - b["two_tau_fc_friction_Nm"]) < abs(b["height_Nm"] - b["two_tau_fc_Nm"])
                  for b in bend if "two_tau_fc_friction_Nm" in b]
        if closer:
            win = "friction_preserving" if 2 * sum(closer) > len(closer) else "field_minimum"
            votes[win] += 1
            parts.append(f"Fig. 7 loop heights (sliding friction of the plant without unmodelled effects) are closer to "
                         f"2τ_fc with the friction-preserving reading on {sum(closer)} of {len(closer)} groups ("
                         + ", ".join(f"θ = {b['theta_rad']:.1f}: {_fmt(b['height_Nm'])} vs "
                                     f"{_fmt(b['two_tau_fc_friction_Nm'])} / {_fmt(b['two_tau_fc_Nm'])} Nm"
                                     for b in bend) + ", measured vs friction-preserving / field minimum)")
    if "fig9_10" in figures:
        g = figures["fig9_10"]["data"]["rmse_Nm"]
        if "friction_preserving" in g and "field_minimum" in g:
            m = {k: _mean([x for r in g[k] for x in r]) for k in votes}
            votes[min(m, key=m.get)] += 1
            parts.append(f"Fig. 10 averaged-pretension mean RMSE over groups and N: {_fmt(m['friction_preserving'])} "
                         f"(friction-preserving) vs {_fmt(m['field_minimum'])} Nm (field minimum)")
    if "fig11" in figures:
        r11 = figures["fig11"]["data"]["rmse_Nm"]
        if all(f"reduced_{k}" in r11.get("stiff", {}) for k in votes):
            m = {k: _mean([x for o in r11.values() for x in o[f"reduced_{k}"]]) for k in votes}
            votes[min(m, key=m.get)] += 1
            parts.append(f"Fig. 11 reduced-model mean RMSE over groups and both outputs: "
                         f"{_fmt(m['friction_preserving'])} vs {_fmt(m['field_minimum'])} Nm")
    choice = max(votes, key=lambda k: (votes[k], k == "friction_preserving"))
    default = FeedforwardConfig().eq25_reading.name.lower()
    text = [f"**Eq 25 reading**: the data favour **{choice.replace('_', ' ')}** ({votes[choice]} of "
            f"{sum(votes.values())} tests): " + "; ".join(parts) + ". The feedforward's default "
            f"(`controller.feedforward.eq25_reading`) is {default.replace('_', ' ')}"
            + (", the same." if default == choice else " - **differs from this run's data**.")]
    return {"votes": votes, "choice": choice, "feedforward_default": default, "text": text}


def _placement(d13: dict[str, Any]) -> dict[str, Any]:
    from capstan.tools.experiments.interaction import CONDITIONS

    means, faulted = d13["mean_abs_tau_h_Nm"], d13["faulted"]
    cases, text = [], []
    for cond, m in means.items():
        f = faulted.get(cond, {})
        base = m.get("pid_gravity_only")
        for ctl in sorted({k.split("@")[0] for k in m if f"{k.split('@')[0]}@motor" in m}):
            ref, mot = m[ctl], m[f"{ctl}@motor"]
            ref_bad, mot_bad = bool(f.get(ctl)), bool(f.get(f"{ctl}@motor"))
            better = "reference" if (ref_bad, ref) <= (mot_bad, mot) else "motor"
            cases.append({"condition": cond, "theta_rad": CONDITIONS[cond].theta_rad if cond in CONDITIONS else None,
                          "controller": ctl, "reference_Nm": ref, "motor_Nm": mot, "reference_faulted": ref_bad,
                          "motor_faulted": mot_bad, "better": better})
        ok = {k: v for k, v in m.items() if not f.get(k) and _finite(v)}
        if ok and _finite(base):
            best = min(ok, key=ok.get)
            th = CONDITIONS[cond].theta_rad if cond in CONDITIONS else float("nan")
            text.append(f"{cond} (θ = {th:g} rad): lowest mean |τ_h| with **{best}** = {_fmt(ok[best])} Nm, "
                        f"{base / ok[best]:.1f}× below the uncompensated {_fmt(base)} Nm.")
    n_ref = sum(c["better"] == "reference" for c in cases)
    head = (f"**Feedforward placement**: the torque reference wins {n_ref} of {len(cases)} comparisons "
            "(mean |τ_h|, reference vs motor command): "
            + "; ".join(f"{c['condition']} {c['controller']}: {_fmt(c['reference_Nm'])} vs {_fmt(c['motor_Nm'])} Nm"
                        + (" (motor run faulted)" if c["motor_faulted"] else "")
                        + (" (reference run faulted)" if c["reference_faulted"] else "") for c in cases) + ".")
    choice = "torque reference" if 2 * n_ref >= len(cases) else "motor command"
    tail = (f"Use the **{choice}** placement" + (" on every condition evaluated." if n_ref in (0, len(cases))
                                                else "; the answer changes with the condition (see above)."))
    return {"per_case": cases, "choice": choice, "reference_wins": n_ref, "cases": len(cases),
            "text": [head + " " + tail] + text}


def _largest_spread(grid: list[list[Any]]) -> float:
    """Largest (max - min) over the finite entries of one row [same unit]."""
    spreads = [max(v) - min(v) for v in ([x for x in r if _finite(x)] for r in grid) if v]
    return max(spreads) if spreads else math.nan


def _mean(vals: list[Any]) -> float:
    v = [x for x in vals if _finite(x)]
    return sum(v) / len(v) if v else math.nan


def _fmt(x: Any) -> str:
    return f"{x:.3f}" if _finite(x) else "n/a"
