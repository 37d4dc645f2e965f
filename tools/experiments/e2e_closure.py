"""End-to-end model closure on the daemon in hardware-in-the-loop mode.

``python -m capstan.tools.experiments.e2e_closure --out DIR [--config config/hil_effect.yaml] [--duration-s 90]
[--retries 1] [--baseline dynamic|static] [--doc docs/e2e-closure.md]``

The real commands, in separate processes, as an operator would run them:

1. run A: ``capstan hil`` with the plant carrying an effect the controller's model lacks
   (``hil.plant.effects`` of the config; the daemon's own controller config);
2. ``capstan close LOG_A --report DIR/close --json``: a single run, split into a contiguous
   training head (70 %) and held-out tail; held-out prediction RMSE before/after. The
   baseline is the dynamic reduced model in its LINK form (the log declares a link output:
   the motor angle and the output load cells drive, tau_in is predicted; ``--baseline
   static`` for the friction-on-velocity regression). Selected effects that no injected one
   accounts for are listed (``not_injected``);
3. the learned fragment ``DIR/close/effects.yaml`` merged into the daemon config
   (``controller.feedforward.effects`` / ``effects_shape``; the fragment's
   ``identification`` section is kept for the record only). Only catalogued effects are
   merged unless ``--with-empirical``: an ``empirical:*`` entry describes how the residual
   depends on a signal when no physical effect explains it; on closed-loop data the
   signal (load, tension) is itself set by the controller, so feeding the curve forward
   extrapolates a correlation of run A's loop, not a mechanism;
4. run B: ``capstan hil`` with the same plant and the merged config;
5. run C (control): ``capstan hil`` without the effect in the plant, original config.

All three runs last ``--duration-s`` seconds of control with the same hand motion. For
each run: the hand's interaction torque (plant statistics, :mod:`capstan.tools.hil.hand`),
the breakaway/sliding friction ratio measured from the daemon's log
(:mod:`capstan.tools.experiments.breakaway`), loop figures and faults. A run that stops on a fault (e.g. a
staleness fault when the machine is loaded) is repeated up to ``--retries`` times; every
attempt is reported. Writes ``DIR/summary.json`` and ``DIR/summary.md`` (and ``--doc``).
Exit code 0 when all runs completed without a fault and the closure ran, else 1.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import yaml

from capstan.models.common.config_tools import load_yaml
from capstan.models.common.errors import CapstanError
from capstan.models.closure.dynamic.candidates import dwell_breakaway_excess_Nm
from capstan.tools.experiments.breakaway import MOVING_RAD_S, breakaways
from capstan.tools.offline.run_inputs import load_run
from capstan.tools.offline.shipped import config_path

#: onsets after shorter rests are not counted in the breakaway figure [s]
MIN_REST_S = 0.3


def is_empirical(entry: Mapping[str, Any]) -> bool:
    """True for an empirical curve of the fragment (no catalogued mechanism)."""
    return str(entry.get("effect", "")).startswith("empirical")


def merge_fragment(cfg: Mapping[str, Any], frag: Mapping[str, Any], empirical: bool = True) -> dict[str, Any]:
    """Copy of the daemon config with the fragment's ``controller.feedforward`` keys merged in
    (without the empirical entries when ``empirical`` is False)."""
    out = copy.deepcopy(dict(cfg))
    ff_new = copy.deepcopy(dict(frag.get("controller", {}).get("feedforward", {})))
    if not empirical:
        ff_new["effects"] = [e for e in ff_new.get("effects", []) if not is_empirical(e)]
    ff = out.setdefault("controller", {}).setdefault("feedforward", {})
    ff.update(ff_new)
    return out


def not_injected(selected: Sequence[Mapping[str, Any]], injected: Sequence[Mapping[str, Any]]) -> list[str]:
    """Names of the selected effects that no injected effect accounts for: a selected effect is
    accounted for when it is an injected one, or an empirical curve of (or a catalogued effect
    depending only on) the signals the injected effects depend on (``empirical:dwell`` for an
    injected ``dwell_stiction``)."""
    from capstan.models.closure.effects import CATALOGUE
    names = {str(e.get("effect")) for e in injected}
    signals = {d for spec in CATALOGUE if spec.name in names for d in spec.depends_on}
    out = []
    for e in selected:
        name = str(e.get("effect", ""))
        deps = set(e.get("depends_on") or [])
        if name in names or (deps and deps <= signals):
            continue
        out.append(name)
    return out


def without_effects(cfg: Mapping[str, Any]) -> dict[str, Any]:
    """Copy of the config whose simulated plant carries no injected effect."""
    out = copy.deepcopy(dict(cfg))
    out.get("hil", {}).get("plant", {}).pop("effects", None)
    return out


def _log(msg: str) -> None:
    print(f"[e2e] {msg}", file=sys.stderr, flush=True)


def run_hil(name: str, cfg: Mapping[str, Any], duration_s: float, out: Path, retries: int) -> dict[str, Any]:
    """``capstan hil`` on ``cfg`` (logging into ``out/logs/NAME``); repeated on a fault.

    :returns: the last attempt's summary plus ``attempts`` (exit code and faults of each).
    """
    attempts: list[dict[str, Any]] = []
    summary: dict[str, Any] = {}
    for k in range(retries + 1):
        c = copy.deepcopy(dict(cfg))
        c.setdefault("logging", {})["dir"] = str(out / "logs" / f"{name}{k}")
        path = out / f"config_{name}.yaml"
        path.write_text(yaml.safe_dump(c, sort_keys=False))
        cmd = [sys.executable, "-m", "capstan.tools.cli", "hil", "--config", str(path), "--duration-s", str(duration_s), "--json"]
        _log(f"run {name} (attempt {k + 1}): {' '.join(cmd[1:])}")
        p = subprocess.run(cmd, capture_output=True, text=True)
        lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
        summary = json.loads(lines[-1]) if lines else {}
        attempts.append({"exit_code": p.returncode, "faults": summary.get("faults", []),
                         "missed": summary.get("missed"), "cycles": summary.get("cycles"),
                         "plant_lost_s": summary.get("plant", {}).get("lost_s")})
        (out / f"hil_{name}.stderr.txt").write_text(p.stderr[-20000:])
        if p.returncode == 0:
            break
        _log(f"run {name} exit code {p.returncode}, faults {summary.get('faults')}")
    summary["attempts"] = attempts
    summary["config_path"] = str(out / f"config_{name}.yaml")
    return summary


def breakaway_figures(log_path: str) -> dict[str, Any]:
    """Breakaway over sliding friction from a daemon log (onsets after rests >= MIN_REST_S,
    the first onset of the log excluded: its rest began before the log)."""
    tb = load_run(log_path)
    ratio = float(tb.meta.get("r_in", 1.0)) / float(tb.meta.get("r_out", 1.0))
    ev = [b for b in breakaways(tb.t, tb["tau_in"], tb["tau_out"], tb["dq_out"], ratio)[1:]
          if b.rest_s >= MIN_REST_S and math.isfinite(b.ratio)]
    ratios = np.array([b.ratio for b in ev])
    return {"onsets": len(ev), "median_ratio": float(np.median(ratios)) if len(ev) else math.nan,
            "max_ratio": float(ratios.max()) if len(ev) else math.nan,
            "median_peak_Nm": float(np.median([b.peak_Nm for b in ev])) if ev else math.nan,
            "median_sliding_Nm": float(np.median([b.sliding_Nm for b in ev])) if ev else math.nan}


def run_close(log_path: str, out: Path, baseline: str = "dynamic") -> dict[str, Any]:
    """``capstan close LOG --report out/close --json --baseline BASELINE``; returns its JSON object.

    :raises CapstanError: if the command fails (its stderr tail in the message).
    """
    # the dynamic baseline in its LINK form: the daemon's log declares a link output, so the motor
    # angle and the output load cells drive the friction-state unit and tau_in is predicted
    cmd = [sys.executable, "-m", "capstan.tools.cli", "close", log_path, "--report", str(out / "close"), "--json",
           "--no-progress", "--baseline", baseline]
    _log("close: " + " ".join(cmd[1:]))
    p = subprocess.run(cmd, capture_output=True, text=True)
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    if p.returncode != 0 or not lines:
        raise CapstanError(f"capstan close failed ({p.returncode}): {p.stderr[-2000:]}")
    return json.loads(lines[-1])


def _fmt(v: Any) -> str:
    return f"{v:.3g}" if isinstance(v, (int, float)) else str(v)


def _run_row(name: str, what: str, r: Mapping[str, Any]) -> str:
    h = (r.get("plant") or {}).get("hand") or {}
    b = r.get("breakaway", {})
    att = r.get("attempts", [])
    return (f"| {name} | {what} | {h.get('mean_abs_tau_h_Nm', math.nan):.3f} | "
            f"{h.get('rms_tau_h_Nm', math.nan):.3f} | "
            f"{h.get('mean_breakaway_peak_tau_h_Nm', math.nan):.3f} | {h.get('max_abs_tau_h_Nm', math.nan):.3f} | "
            f"{b.get('median_ratio', math.nan):.2f} ({b.get('onsets', 0)}) | {r.get('cycles', 0)} | {r.get('missed', 0)} | "
            f"{', '.join(r.get('faults', [])).replace('|', chr(92) + '|') or 'none'} | {len(att)} |")


def markdown(s: Mapping[str, Any]) -> str:
    """The Markdown summary of :func:`main`'s result."""
    runs, cl = s["runs"], s["closure"]
    inj = ", ".join(f"{e['effect']} (" + ", ".join(f"{k} {v:g}" for k, v in e.items() if k != "effect") + ")"
                    for e in s["injected"])
    lines = [
        "# End-to-end model closure on the daemon (hardware in the loop)",
        "",
        f"Generated by `{s['command']}` on {s['date']} ({s['machine']}; load average "
        f"{s['loadavg_start'][0]:.2f} at the start, {s['loadavg_end'][0]:.2f} at the end).",
        "",
        f"The simulated rig (`{s['config']}`) carries an effect the controller's model lacks: **{inj}**. "
        "A hand (arm impedance, `hil.hand`) moves the link from stop to stop within 0-1 rad with rests of "
        "0.3-3 s; every run sees the same hand motion. "
        "Run A: the daemon with its reduced-model feedforward. `capstan close` on A's log (70 % head "
        "training, 30 % tail held out) finds the residual, traces it and writes the fragment; run B: the same "
        "plant with the fragment's catalogued effects merged into the daemon config. Run C (control): no effect in the plant, "
        "original config.",
        "",
        "## Prediction error (held-out tail of run A, `capstan close`)",
        "",
        "| | RMSE [Nm] | max error [Nm] |",
        "|---|---|---|",
        f"| baseline ({_baseline_label(cl['baseline'])}) | {cl['baseline']['rmse_Nm']:.4f} | "
        f"{cl['baseline']['max_err_Nm']:.3f} |",
        f"| with the selected effects | {cl['final']['rmse_Nm']:.4f} | {cl['final']['max_err_Nm']:.3f} |",
    ] + [f"| baseline + {c['effect']} alone (round 1) | {c['rmse_Nm']:.4f} | {c['max_err_Nm']:.3f} |"
         for c in cl.get("candidates", []) if c["round"] == 1 and c["target"] == "tau_out"
         and any(e["effect"] == c["effect"] for e in cl["selected"]) and not c["effect"].startswith("empirical")] + [
        "",
        f"Held-out RMSE {100 * (1 - cl['final']['rmse_Nm'] / cl['baseline']['rmse_Nm']):.1f} % lower. Selected: "
        + ("; ".join(f"**{e['effect']}** ({', '.join(e['depends_on'])}; improvement {100 * e['improvement']:.1f} %; "
                     + ", ".join(f"{k} {_fmt(v)}" for k, v in e["params"].items()) + ")" for e in cl["selected"])
           or "nothing") + ".",
        "",
        _baseline_line(cl["baseline"], cl["final"]),
        "",
        "Selected although not injected: " + (", ".join(s.get("not_injected", [])) or "none") + ".",
        "",
        "## Interaction torque and breakaway friction",
        "",
        "Interaction torque `tau_h` (what a handle F/T sensor reads) after the hand's first 0.5 s; breakaway peak: "
        "mean over strokes of the peak `|tau_h|` in the first 0.5 s of each stroke. Breakaway/sliding: measured "
        "friction `tau_in - tau_out` (load cells) at motion onset over the sliding friction later in the stroke, "
        "median over onsets after rests >= 0.3 s (count in brackets).",
        "",
        "| run | plant / controller | mean \\|tau_h\\| [Nm] | RMS tau_h [Nm] | breakaway peak \\|tau_h\\| [Nm] | "
        "max \\|tau_h\\| [Nm] | breakaway/sliding friction | cycles | missed | faults | attempts |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
        _run_row("A", "effect / reduced-model feedforward", runs["A"]),
        _run_row("B", "effect / + learned effects", runs["B"]),
        _run_row("C", "no effect / reduced-model feedforward", runs["C"]),
        "",
    ]
    ha, hb, hc = (((runs[k].get("plant") or {}).get("hand") or {}) for k in "ABC")
    try:
        gap_a = ha["mean_abs_tau_h_Nm"] - hc["mean_abs_tau_h_Nm"]
        gap_b = hb["mean_abs_tau_h_Nm"] - hc["mean_abs_tau_h_Nm"]
        pk_a = ha["mean_breakaway_peak_tau_h_Nm"] - hc["mean_breakaway_peak_tau_h_Nm"]
        pk_b = hb["mean_breakaway_peak_tau_h_Nm"] - hc["mean_breakaway_peak_tau_h_Nm"]
        lines += [f"Mean |tau_h| A -> B: {ha['mean_abs_tau_h_Nm']:.3f} -> {hb['mean_abs_tau_h_Nm']:.3f} Nm "
                  f"({100 * (1 - hb['mean_abs_tau_h_Nm'] / ha['mean_abs_tau_h_Nm']):.1f} % lower); the excess over "
                  f"the control run C falls from {gap_a:.3f} to {gap_b:.3f} Nm. Breakaway peak excess over C: "
                  f"{pk_a:.3f} -> {pk_b:.3f} Nm.", ""]
    except (KeyError, TypeError):
        lines += ["(interaction figures incomplete: see summary.json)", ""]
    lines += _parameters(s)
    lines += ["Empirical curves (`empirical:*`: the residual's dependence on a signal no catalogued effect "
              "explains) are reported by the closure but not merged by default: on closed-loop data the load "
              "and the tensions are set by the controller itself, so the curve is a correlation of run A's loop, "
              "not a mechanism, and feeding it forward changes what it was fitted on "
              "(`--with-empirical` merges them).", ""]
    lines += ["Learned effects merged for run B (`controller.feedforward`; the fragment's empirical curves "
              "left out: " + (", ".join(s["left_out"]) or "none") + "):", "", "```yaml",
              yaml.safe_dump({"effects": s["learned"], "effects_shape": s["learned_shape"]},
                             sort_keys=False).rstrip(), "```", "",
              "Reproduce: `" + s["command"] + "` (several minutes: the HIL runs are real time). "
              "Per-run JSON summaries, configs, logs and the closure report (`close/report.md`) are in the "
              "output directory.", ""]
    return "\n".join(lines)


def _baseline_label(b: Mapping[str, Any]) -> str:
    form = b.get("form", "")
    return f"reduced model, {form}" if form else "reduced model"


def _baseline_line(b: Mapping[str, Any], f: Mapping[str, Any]) -> str:
    """The baseline's driving form, target, skill (the dynamic baseline's report keys)."""
    if "target" not in b:
        return "Baseline: the static friction-on-velocity regression."
    return (f"Baseline: the dynamic reduced model, form {b.get('form', '?')} ({b.get('form_reason', '')}); predicts "
            f"{b['target']} from {', '.join(b.get('driving', []))}; held-out std of {b['target']} "
            f"{b.get('target_std_Nm', math.nan):.3f} Nm, skill {b.get('skill', math.nan):.3f} (baseline) -> "
            f"{f.get('skill', math.nan):.3f} (with the selected effects).")


def write_markdown(summary: Mapping[str, Any], out: Path, doc: str | None) -> str:
    """Write ``out/summary.md`` (and ``doc``); returns the text."""
    md = markdown(summary)
    (out / "summary.md").write_text(md)
    if doc:
        Path(doc).write_text(md)
    return md


def _parameters(s: Mapping[str, Any]) -> list[str]:
    """Injected against learned dwell-stiction parameters (amplitude in Nm via the measured sliding friction)."""
    inj = [e for e in s["injected"] if e.get("effect") == "dwell_stiction"]
    got = [e for e in s["learned"] if e.get("effect") == "dwell_stiction"]
    slide = s["runs"]["C"].get("breakaway", {}).get("median_sliding_Nm", math.nan)
    if not inj or not got:
        return []
    i, g = inj[0], got[0]["params"]
    sh = s.get("learned_shape") or {}
    # amp scales the capacity with its Stribeck peak: the excess at an onset (long rest)
    onset = float(dwell_breakaway_excess_Nm(g["amp_Nm"], g["tau_age_s"], math.inf, sh.get("zeta_s", 1.0),
                                            sh.get("eta_s_rad_s", 1.0), MOVING_RAD_S))
    return [f"Dwell stiction, injected -> learned: amplitude {i['amp']:g} x sliding friction {slide:.2f} Nm "
            f"(run C) = {i['amp'] * slide:.2f} Nm -> amp_Nm {g['amp_Nm']:.2f} Nm, at an onset after a long rest "
            f"{onset:.2f} Nm (x the refitted Stribeck factor, zeta_s {sh.get('zeta_s', 1.0):.3g}); ageing time "
            f"constant {i['tau_age_s']:g} s -> {g['tau_age_s']:g} s; slide to lose it {i['slide_rad']:g} rad -> "
            f"s0 {g['s0_rad']:g} rad (the closure picks these two from a grid).", ""]


def main(argv: Sequence[str] | None = None) -> int:
    """Run the pipeline; returns the exit code."""
    ap = argparse.ArgumentParser(prog="python -m capstan.tools.experiments.e2e_closure", description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True, help="output directory")
    ap.add_argument("--config", default=str(config_path("hil_effect.yaml")), help="HIL config with the effect")
    ap.add_argument("--duration-s", type=float, default=90.0, help="seconds of control of each run")
    ap.add_argument("--duration", dest="duration_s", type=float, help=argparse.SUPPRESS)   # deprecated spelling
    ap.add_argument("--retries", type=int, default=1, help="repeats of a run that stopped on a fault")
    ap.add_argument("--baseline", choices=("dynamic", "static"), default="dynamic",
                    help="baseline of capstan close (dynamic: the reduced model simulated, LINK form on a daemon log)")
    ap.add_argument("--with-empirical", action="store_true", help="also merge the empirical curves into run B")
    ap.add_argument("--doc", help="also write the Markdown summary here (e.g. docs/e2e-closure.md)")
    ap.add_argument("--render", action="store_true", help="only rewrite the Markdown from DIR/summary.json")
    args = ap.parse_args(argv)
    out = Path(args.out).resolve()
    if args.render:
        write_markdown(json.loads((out / "summary.json").read_text()), out, args.doc)
        return 0
    out.mkdir(parents=True, exist_ok=True)
    cfg = load_yaml(args.config)
    injected = cfg.get("hil", {}).get("plant", {}).get("effects") or []
    if not injected:
        _log(f"{args.config}: hil.plant.effects is empty: nothing for the closure to find")
        return 1
    load0 = os.getloadavg()
    runs: dict[str, dict[str, Any]] = {}
    runs["A"] = run_hil("A", cfg, args.duration_s, out, args.retries)
    if not runs["A"].get("log_path"):
        _log("run A produced no log")
        return 1
    try:
        closure = run_close(runs["A"]["log_path"], out, args.baseline)
    except CapstanError as exc:
        _log(str(exc))
        return 1
    frag = load_yaml(out / "close" / "effects.yaml")
    merged = merge_fragment(cfg, frag, empirical=args.with_empirical)
    runs["B"] = run_hil("B", merged, args.duration_s, out, args.retries)
    left_out = [e["effect"] for e in frag.get("controller", {}).get("feedforward", {}).get("effects", [])
                if not args.with_empirical and is_empirical(e)]
    runs["C"] = run_hil("C", without_effects(cfg), args.duration_s, out, args.retries)
    for r in runs.values():
        r["breakaway"] = breakaway_figures(r["log_path"]) if r.get("log_path") else {}
    shown = os.path.relpath(args.config) if Path(args.config).resolve().is_relative_to(Path.cwd()) else args.config
    cmd = " ".join(["python -m capstan.tools.experiments.e2e_closure", "--out", args.out, "--config", shown,
                    "--duration-s", f"{args.duration_s:g}"] + (["--baseline", "static"] if args.baseline == "static" else []) + (["--with-empirical"] if args.with_empirical else [])
                   + (["--doc", args.doc] if args.doc else []))
    summary = {
        "command": cmd, "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "machine": f"{os.cpu_count()} CPU, {platform.machine()}, Python {platform.python_version()}",
        "loadavg_start": list(load0), "loadavg_end": list(os.getloadavg()),
        "config": shown,
        "injected": injected,
        "closure": {k: closure[k] for k in ("baseline", "final", "selected", "candidates", "data", "trace")},
        "learned": merged["controller"]["feedforward"].get("effects", []),
        "learned_shape": merged["controller"]["feedforward"].get("effects_shape", {}),
        "left_out": left_out,
        "not_injected": not_injected(closure["selected"], injected),
        "identification": frag.get("identification", {}), "runs": runs,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
    print(write_markdown(summary, out, args.doc))
    ok = all(r["attempts"][-1]["exit_code"] == 0 for r in runs.values())
    return 0 if ok else 1


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
