"""Report of a model closure: the JSON summary, the controller config fragment, and a
Markdown page with PNG plots (residual against the attributed signal before/after,
time series, hysteresis loops) in a report directory.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from capstan.models.closure.pipeline import Candidate, ClosureResult
from capstan.models.closure.dynamic.closure import skill
from capstan.models.closure.effects import Target
from capstan.models.closure.effects_runtime import EffectCode, signal_code
from capstan.models.closure.residual_trace import is_empirical

_CODES = {"dwell_stiction": EffectCode.DWELL_STICTION, "speed_viscous": EffectCode.SPEED_VISCOUS,
          "position_friction": EffectCode.POSITION_FRICTION,
          "pretension_relaxation": EffectCode.PRETENSION_RELAXATION, "load_friction": EffectCode.LOAD_FRICTION,
          "temperature_drift": EffectCode.TEMPERATURE_DRIFT, "tension_friction": EffectCode.TENSION_FRICTION,
          "output_inertia": EffectCode.OUTPUT_INERTIA}


def _selected_params(c: Candidate) -> dict[str, Any]:
    d: dict[str, Any] = {**c.params, **{k: v for k, v in c.shape.items()}}
    if c.description:
        d = {"description": c.description["text"]}
    return d


def summary(res: ClosureResult, train_names: list[str], test_names: list[str], model: str) -> dict[str, Any]:
    """The ``--json`` object of ``capstan close``."""
    main = res.targets[Target.TAU_OUT]
    out: dict[str, Any] = {
        "baseline": {"model": model, "rmse_Nm": main.rmse_before_Nm, "max_err_Nm": main.max_before_Nm,
                     "params": res.baseline.params, "stderr": res.baseline.stderr},
        "candidates": [c.summary() for t in res.targets.values() for c in t.candidates],
        "selected": [{"effect": c.effect, "depends_on": c.depends_on, "target": c.target.name.lower(),
                      "improvement": c.improvement, "params": _selected_params(c),
                      "params_stderr": c.params_stderr, "params_interval": c.params_interval,
                      "no_effect_p": c.no_effect_p, "description": (c.description or {}).get("text", c.words)}
                     for t in res.targets.values() for c in t.selected],
        "final": {"rmse_Nm": main.rmse_after_Nm, "max_err_Nm": main.max_after_Nm},
        "trace": res.trace,
        "data": {"train": train_names, "test": test_names},
    }
    _dynamic_keys(res, out)
    if Target.ELASTIC in res.targets:
        el = res.targets[Target.ELASTIC]
        out["elastic"] = {"baseline_rmse_Nm": el.rmse_before_Nm, "final_rmse_Nm": el.rmse_after_Nm,
                          "baseline_max_err_Nm": el.max_before_Nm, "final_max_err_Nm": el.max_after_Nm}
    unexplained = [c.description["text"] for t in res.targets.values() for c in t.selected if c.description]
    if unexplained:
        out["unexplained"] = unexplained
    return out


def _dynamic_keys(res: ClosureResult, out: dict[str, Any]) -> None:
    """baseline.target / driving / target_std_Nm and skill (baseline and final); with the
    dynamic baseline also its parameters, their status and the excluded signals. The
    static regression's parameters stay under ``baseline.feedforward`` (the controller's map)."""
    main = res.targets[Target.TAU_OUT]
    b, f = out["baseline"], out["final"]
    ds = res.dynamic
    std = float(np.std(ds.y_test_Nm if ds is not None else main.y_test))
    b["target_std_Nm"] = std
    b["skill"] = skill(main.rmse_before_Nm, std)
    f["skill"] = skill(main.rmse_after_Nm, std)
    if ds is None:
        b["target"], b["driving"] = "tau_out", ["tau_in", "dq_out"]
        b["form"] = "static friction-on-velocity regression"
        return
    fit = ds.fit
    b["feedforward"] = {"params": b["params"], "stderr": b["stderr"]}
    b.update({"simulation": "dynamic: the reduced model integrated through each run, friction as a state", "target": fit.spec.target,
              "driving": list(fit.spec.driving), "form": fit.spec.form.name.lower(), "form_reason": fit.spec.reason,
              "params": fit.params, "stderr": fit.stderr, "at_bound": fit.at_bound, "implausible": fit.implausible,
              "undetermined": fit.undetermined, "warnings": fit.warnings, "train_rmse_Nm": fit.rmse_Nm,
              "n_train_samples": fit.n_samples})
    out["excluded"] = [{"signal": k, "reason": v} for k, v in sorted(ds.excluded.items())]


def fragment(res: ClosureResult, model: str, refs: dict[str, float], q_ref_rad: float) -> dict[str, Any]:
    """Controller config fragment (format in :mod:`capstan.models.closure.effects_runtime`)."""
    effects = []
    for t in res.targets.values():
        for c in t.selected:
            p = [0.0] * 8
            entry: dict[str, Any] = {"effect": c.effect, "depends_on": c.depends_on,
                                     "params": {k: v for k, v in _selected_params(c).items()}}
            code = _CODES.get(c.effect, EffectCode.INFO)
            prm, sh = c.params, c.shape
            if code == EffectCode.DWELL_STICTION:
                p[:3] = [prm["amp_Nm"], float(sh["tau_age_s"]), float(sh["s0_rad"])]
            elif code == EffectCode.SPEED_VISCOUS:
                p[:2] = [prm["c2_Nms2_rad2"], prm["c3_Nms3_rad3"]]
            elif code == EffectCode.POSITION_FRICTION:
                p[:3] = [prm["a1_Nm_rad"], prm["a2_Nm_rad2"], q_ref_rad]
            elif code == EffectCode.PRETENSION_RELAXATION:
                p[:2] = [prm["d_Nm"], float(sh["tau_r_s"])]
            elif code == EffectCode.LOAD_FRICTION:
                p[0] = prm["c_load"]
            elif code == EffectCode.TEMPERATURE_DRIFT:
                ch = str(sh["channel"])
                p[:3] = [prm["ct_Nm_K"], prm["co_Nm_K"], refs.get(ch, 0.0)]
                entry["aux"] = ch
            elif code == EffectCode.TENSION_FRICTION:
                p[:2] = [prm["c_Nm_N"], refs.get("tension", 0.0)]
                entry["aux"] = "tension"
            elif code == EffectCode.OUTPUT_INERTIA:
                p[0] = prm["J_kg_m2"]
            if c.spec is not None and is_empirical(c.spec) and c.target == Target.TAU_OUT and c.description:
                code = EffectCode.EMPIRICAL
                k = len(c.description["knots"])
                sig = c.depends_on[0]
                p[0] = float(signal_code(sig))
                entry.update({"knots": c.description["knots"], "even": c.description["curve"][:k],
                              "odd": c.description["curve"][k:2 * k]})
                if p[0] == 6:
                    entry["aux"] = sig
            entry["code"] = int(code)
            entry["p"] = [float(x) for x in p]
            effects.append(entry)
    # the effects' coefficients were fitted together with a refitted baseline: the shape they
    # are evaluated with, and the baseline recorded beside them, are that refit's
    tau_out = res.targets.get(Target.TAU_OUT)
    b = tau_out.params_after if tau_out is not None and tau_out.selected and tau_out.params_after \
        else res.baseline.params
    return {"controller": {"feedforward": {
                "effects": effects,
                "effects_shape": {"alpha_s_rad": b.get("alpha_s_rad", 1.0), "eta_s_rad_s": b.get("eta_s_rad_s", 1.0),
                                  "zeta_s": b.get("zeta_s", 1.0),
                                  "v_rest_rad_s": float(res.train.v_rest_rad_s)}}},
            "identification": {"model": model, "params": b, "stderr": res.baseline.stderr,
                               "baseline_alone": res.baseline.params}}


def write_fragment(frag: dict[str, Any], path: Path) -> Path:
    """Write the fragment YAML with a header comment."""
    text = ("# Learned transmission effects (capstan close). Merge into the daemon config;\n"
            "# format: models/closure/effects_runtime.py. identification: the baseline they were fitted on.\n")
    path.write_text(text + yaml.safe_dump(frag, sort_keys=False))
    return path


def _plots(res: ClosureResult, outdir: Path) -> list[tuple[str, str]]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pics: list[tuple[str, str]] = []
    sig = res.test
    for tgt, tr in res.targets.items():
        r0 = tr.y_test - tr.pred_before
        r1 = tr.y_test - tr.pred_after
        tag = tgt.name.lower()
        t = sig.t_s
        fig, ax = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
        ax[0].plot(t, tr.y_test, lw=0.6, label="measured")
        ax[0].plot(t, tr.pred_before, lw=0.6, label="baseline")
        ax[0].plot(t, tr.pred_after, lw=0.6, label="with selected effects")
        ax[0].set_ylabel("Nm")
        ax[0].legend(loc="upper right", fontsize=8)
        ax[1].plot(t, r0, lw=0.5, label=f"residual before (RMSE {tr.rmse_before_Nm:.3g})")
        ax[1].plot(t, r1, lw=0.5, label=f"residual after (RMSE {tr.rmse_after_Nm:.3g})")
        ax[1].set_xlabel("t [s] (held-out)")
        ax[1].set_ylabel("Nm")
        ax[1].legend(loc="upper right", fontsize=8)
        fn = f"timeseries_{tag}.png"
        fig.tight_layout()
        fig.savefig(outdir / fn, dpi=90)
        plt.close(fig)
        pics.append((f"Held-out time series ({tag})", fn))
        if tgt == Target.TAU_OUT:
            fig, ax = plt.subplots(1, 2, figsize=(10, 4.5), sharey=True)
            for a, pred, name in ((ax[0], tr.pred_before, "baseline"), (ax[1], tr.pred_after, "with effects")):
                a.plot(sig.tau_in_Nm, tr.y_test, ",", alpha=0.5, label="measured")
                a.plot(sig.tau_in_Nm, pred, ",", alpha=0.5, label=name)
                a.set_xlabel("tau_in [Nm]")
                a.set_title(f"hysteresis loop: {name}")
            ax[0].set_ylabel("tau_out [Nm]")
            fn = "hysteresis.png"
            fig.tight_layout()
            fig.savefig(outdir / fn, dpi=90)
            plt.close(fig)
            pics.append(("Hysteresis loops (held-out)", fn))
        attributed = [c.depends_on[0] for c in tr.selected]
        for name in dict.fromkeys(attributed):
            x = sig.signal(name) if name != "latency" else None
            if x is None:
                x, name = sig.dq_out_rad_s, f"{name} (shown against velocity)"
            fig, ax = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
            ax[0].plot(x, r0, ",", alpha=0.4)
            ax[0].set_title("residual before")
            ax[1].plot(x, r1, ",", alpha=0.4)
            ax[1].set_title("residual after")
            for a in ax:
                a.set_xlabel(name)
            ax[0].set_ylabel("residual [Nm]")
            fn = f"residual_vs_{name.split()[0]}_{tag}.png"
            fig.tight_layout()
            fig.savefig(outdir / fn, dpi=90)
            plt.close(fig)
            pics.append((f"Residual against {name} ({tag})", fn))
    return pics


def _with_error(k: str, v: Any, stderr: dict[str, float] | None) -> str:
    """``k=v`` with ``+- stderr`` where the parameter has one."""
    if not isinstance(v, float):
        return f"{k}={v}"
    se = (stderr or {}).get(k)
    return f"{k}={v:.4g} +- {se:.2g}" if se is not None else f"{k}={v:.4g}"


def write_report(res: ClosureResult, summ: dict[str, Any], outdir: Path, attribution: list[str]) -> Path:
    """Write ``report.md`` + PNGs into ``outdir``; returns the Markdown path."""
    outdir.mkdir(parents=True, exist_ok=True)
    pics = _plots(res, outdir)
    b = summ["baseline"]
    L = ["# Model closure report", "",
         f"Training runs: {', '.join(summ['data']['train'])}  ",
         f"Held-out runs: {', '.join(summ['data']['test'])}", "",
         "## Held-out error before and after", "",
         "| prediction | RMSE before [Nm] | RMSE after [Nm] | max before [Nm] | max after [Nm] |",
         "|---|---|---|---|---|",
         f"| tau_out (friction path) | {b['rmse_Nm']:.4g} | {summ['final']['rmse_Nm']:.4g} | "
         f"{b['max_err_Nm']:.4g} | {summ['final']['max_err_Nm']:.4g} |"]
    if "elastic" in summ:
        e = summ["elastic"]
        L.append(f"| tau_in + tau_out (elastic path) | {e['baseline_rmse_Nm']:.4g} | {e['final_rmse_Nm']:.4g} | "
                 f"{e['baseline_max_err_Nm']:.4g} | {e['final_max_err_Nm']:.4g} |")
    L += ["", f"## Baseline ({b['model']}), fitted on the training runs", "", "| parameter | value | 1-sigma |",
          "|---|---|---|"]
    L += [f"| {k} | {v:.6g} | {b['stderr'].get(k, float('nan')):.3g} |" for k, v in b["params"].items()]
    L += ["", "## Residual trace (round 1, held-out)", "",
          "Share of the held-out residual variance a smooth function of each signal explains.", "",
          "| signal | explained | significant |", "|---|---|---|"]
    L += [f"| {d['signal']} | {d['explained']:.1%} | {'yes' if d['significant'] else 'no'} |" for d in summ["trace"]]
    L += ["", "## Candidates tried", "",
          "Improvement = relative held-out RMSE reduction against the model of that round; "
          "significant = block-bootstrap 95 % lower bound > 0 and improvement >= 5 %.", "",
          "| round | target | effect | depends on | RMSE [Nm] | improvement | 95 % lower | significant |",
          "|---|---|---|---|---|---|---|---|"]
    L += [f"| {c['round']} | {c['target']} | {c['effect']} | {', '.join(c['depends_on'])} | {c['rmse_Nm']:.4g} | "
          f"{c['improvement']:.1%} | {c['improvement_ci_low']:.1%} | {'yes' if c['significant'] else 'no'} |"
          if not c.get("screened_out") else
          f"| {c['round']} | {c['target']} | {c['effect']} | {', '.join(c['depends_on'])} | - | - | - | "
          f"no ({c['screened_out']}) |"
          for c in summ["candidates"]]
    L += ["", "## Selected", ""]
    if not summ["selected"]:
        L.append("Nothing: no candidate improved the held-out prediction significantly.")
    for s in summ["selected"]:
        L.append(f"- **{s['effect']}** ({', '.join(s['depends_on'])}, {s['target']}): "
                 f"{s['improvement']:.1%} lower held-out RMSE; "
                 + ", ".join(_with_error(k, v, s.get("params_stderr")) for k, v in s["params"].items()))
        if s.get("description"):
            L.append(f"  {s['description']}")
        if s.get("params_interval"):
            L.append("  95 % intervals (linearised block bootstrap over 0.5 s windows): "
                     + ", ".join(f"{k} [{a:.4g}, {b:.4g}]" for k, (a, b) in s["params_interval"].items()
                                 if not k.startswith("coef:"))
                     + f"; no effect rejected at p {s['no_effect_p']:.2g}")
    dropped = [c for c in summ["candidates"] if c.get("no_effect")]
    if dropped:
        L += ["", "Not selected because their parameters' interval includes no effect:", ""]
        L += [f"- {c['effect']} ({', '.join(c['depends_on'])}): {c['no_effect']}; "
              + ", ".join(_with_error(k, v, c.get("params_stderr")) for k, v in c.get("params", {}).items())
              for c in dropped]
    L += ["", "## Plots", ""]
    L += [f"### {title}\n\n![{title}]({fn})\n" for title, fn in pics]
    if attribution:
        L += ["## Data attribution", ""] + [f"> {a}" for a in attribution]
    path = outdir / "report.md"
    path.write_text("\n".join(L) + "\n")
    return path
