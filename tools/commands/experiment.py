"""``capstan experiment``: the interaction experiment (paper §4.5, Fig. 13) on the simulated
rig, and ``paper`` (reproduce the paper's figures; implemented in :mod:`capstan.tools.experiments.paper.experiment`).

    capstan experiment interaction [--json] [--quick] [--duration-s S] [--seed N] [--delay-cycles D | --lock-step]
                                   [--terms]      # the shipped loop with one term off at a time
    capstan experiment loop [--config FILE] [--log HIL.mcap] [--json]   # margins with the I/O delay
    capstan experiment paper [...]            # options of capstan.tools.experiments.paper
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import importlib.util
import json
import logging
import sys
from pathlib import Path

HELP = "experiments: interaction (Fig. 13 on the simulated rig), paper (reproduce the paper)"

#: the paper's Fig. 13(d) mean |tau_h| [Nm]: uncompensated, then the compensated cases
PAPER_FIG13_NM = {"uncompensated": 3.370, "compensated": (0.642, 0.498, 1.334, 0.663)}

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Subcommands ``interaction`` and ``paper``."""
    sub = parser.add_subparsers(dest="experiment", required=True)
    p = sub.add_parser("interaction", help="mean |tau_h| per controller and condition (Fig. 13)")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.add_argument("--quick", action="store_true", help="one motion cycle per condition (~10 s wall time)")
    p.add_argument("--duration-s", type=float, default=None, help="simulated time per run [s] (default 24, quick 6.5)")
    p.add_argument("--seed", type=int, default=0, help="sensor-noise seed")
    p.add_argument("--delay-cycles", type=int, default=None,
                   help="command delay of the loop [cycles] (default: controller.stability.io_delay_cycles, 2)")
    p.add_argument("--lock-step", action="store_true", help="the lock-step idealisation (no delay)")
    p.add_argument("--terms", action="store_true",
                   help="break the shipped loop's mean |tau_h| down by term (one switched off at a time)")
    lp = sub.add_parser("loop", help="torque-loop margins and noise gains with the I/O delay")
    from capstan.tools.experiments.loop import add_arguments as _loop_args
    _loop_args(lp)
    q = sub.add_parser("paper", help="reproduce the paper's figures (capstan.tools.experiments.paper)")
    # the paper experiment declares its own options; imported only when this command runs
    if importlib.util.find_spec("capstan.tools.experiments.paper.experiment") is not None:
        module = importlib.import_module("capstan.tools.experiments.paper.experiment")
        if hasattr(module, "add_arguments"):
            module.add_arguments(q)
            q.add_argument("--json", action="store_true", help="print the summary as one JSON object")
            return
    q.add_argument("paper_args", nargs=argparse.REMAINDER, help="arguments passed to the paper experiment")


def run(args: argparse.Namespace) -> int:
    """Run the chosen experiment; returns the exit code."""
    if args.experiment == "paper":
        return _run_paper(args)
    if args.experiment == "loop":
        from capstan.tools.experiments.loop import run as run_loop
        return run_loop(args)
    from capstan.tools.experiments.interaction import run_experiment

    duration = args.duration_s if args.duration_s is not None else (6.5 if args.quick else 24.0)
    if args.lock_step:
        delay = 0
    elif args.delay_cycles is not None:
        delay = args.delay_cycles
    else:
        from capstan.controller.law.config import StabilitySettings
        delay = StabilitySettings().io_delay_cycles
    progress = None if args.json else (lambda m: log.info("%s", m))
    if getattr(args, "terms", False):
        from capstan.tools.experiments.interaction_terms import format_terms, run_terms
        terms = run_terms(duration, delay, seed=args.seed, progress=progress)
        if args.json:     # strict JSON: a margin without a crossover (inf) or a stopped run (nan) -> null
            from capstan.tools.experiments.loop import _finite_or_null
            json.dump(_finite_or_null(terms), sys.stdout, indent=2, allow_nan=False)
            sys.stdout.write("\n")
        else:
            print(format_terms(terms))
        return 0
    out = run_experiment(duration, seed=args.seed, delay_cycles=delay, progress=progress)
    out["duration_s"] = duration
    out["ratios"] = _ratios(out["results"])
    out["paper_fig13_Nm"] = PAPER_FIG13_NM
    if args.json:
        json.dump(out, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    _print_table(out)
    return 0


def _ratios(results: dict) -> dict:
    """Uncompensated mean |tau_h| over each controller's, per condition. The uncompensated run is
    the gravity-only controller of the same torque loop and gains (``interaction.BASELINE``):
    the paper's PID for the paper's controllers, the shipped loop's for ``shipped_*``."""
    from capstan.tools.experiments.interaction import BASELINE
    ratios = {}
    for cond, res in results.items():
        ratios[cond] = {}
        for k, v in res.items():
            base = res.get(BASELINE.get(k.split("@")[0], "pid_gravity_only"), {}).get("mean_abs_tau_h_Nm", float("nan"))
            ratios[cond][k] = base / v["mean_abs_tau_h_Nm"] if v["mean_abs_tau_h_Nm"] > 0 else float("nan")
    return ratios


def _print_table(out: dict) -> None:
    print(f"interaction experiment, {out['duration_s']:.1f} s simulated per run, mean |tau_h| [Nm]; "
          f"loop: {out['loop']}")
    for cond, res in out["results"].items():
        c = out["conditions"][cond]
        h = c["human"]
        print(f"\n{cond}: theta = {c['theta_rad']} rad, pretension = {c['pretension_N']} N, "
              f"human K = {h['stiffness_Nm_rad']} Nm/rad, B = {h['damping_Nms_rad']} Nms/rad, "
              f"stroke {2 * h['amplitude_rad']:.2f} rad in {h['move_s']} s, rests {h['rest_s']} s")
        print(f"  {'controller':<26}{'mean|tau_h|':>12}{'ratio*':>8}{'rms e_tau_in':>14}{'max|raw|':>10}  fault")
        for key, m in res.items():
            if "error" in m:
                print(f"  {key:<26}{'-':>12}  stopped: {m['error']}")
                continue
            print(f"  {key:<26}{m['mean_abs_tau_h_Nm']:>12.3f}{out['ratios'][cond][key]:>8.2f}"
                  f"{m['rms_tau_in_err_Nm']:>14.3f}{m['max_abs_tau_m_raw_Nm']:>10.2f}  {'YES' if m['faulted'] else 'no'}")
    print("\n* ratio: the gravity-only run of the same loop and gains over this one (paper controllers: "
          "pid_gravity_only, lock-step gains; shipped_*: shipped_gravity_only, no inertia compensation)")
    print(f"\npaper Fig. 13(d): {PAPER_FIG13_NM['uncompensated']} Nm uncompensated vs "
          f"{', '.join(str(v) for v in PAPER_FIG13_NM['compensated'])} Nm compensated")


def _run_paper(args: argparse.Namespace) -> int:
    """Delegate to ``capstan.tools.experiments.paper.experiment.run(args)`` (with ``--json``: its
    ``run_paper`` and one JSON object of the summary).

    :raises ConfigError: if the paper experiment module is not installed.
    """
    if importlib.util.find_spec("capstan.tools.experiments.paper.experiment") is None:
        from capstan.models.common.errors import ConfigError

        raise ConfigError("experiment", "the 'paper' experiment (capstan.tools.experiments.paper) is not available")
    module = importlib.import_module("capstan.tools.experiments.paper.experiment")
    if not getattr(args, "json", False):
        return int(module.run(args) or 0)
    settings = module.Settings.quick_settings() if args.quick else module.Settings()
    doc = module.run_paper(Path(args.out), dataclasses.replace(settings, seed=args.seed), module.parse_only(args.only))
    print(json.dumps({"report": str(Path(args.out) / "report.md"), "total_wall_s": doc["total_wall_s"],
                      "figures": {k: {"wall_s": r["wall_s"], "rows": len(r["rows"]), "figures": list(r["figures"])}
                                  for k, r in doc["figures"].items()},
                      "failed": dict(doc["failed"])}))
    return 1 if doc["failed"] else 0
