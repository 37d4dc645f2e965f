"""``capstan identify RUN... [--model reduced|wu] [--import DESC] [--json]``: fit the
transmission model's free parameters with uncertainties and print the fit error.

What each model fits (see :mod:`capstan.models.closure.identification`):

* ``reduced`` (default): eq 20/21 in the friction-on-measured-velocity form
  ``tau_out = g tau_in - tau_fc_hat(dq_out) + c``: ratio g, friction magnitude tau_fc
  (= mu theta T0_eq r_out, eq 19), stiction ratio zeta_s, Stribeck velocity eta_s,
  tanh steepness alpha, viscous b_vis (absorbs gamma), sensor offset c.
* ``wu``: Wu-type mapping, Coulomb friction with a load-proportional part.
* ``distributed``: refused with a clear message (node states are not observable).

Both also report the torsional stiffness K_c from the elastic path (if q_in is
measured) and the testbed environment k_out, b_out (eq 22) with its R^2.
"""

from __future__ import annotations

import argparse
import json

HELP = "fit model parameters (stiffness, friction magnitude, Stribeck shape, environment) with uncertainties"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``capstan identify``."""
    parser.add_argument("runs", nargs="+", help="measurement tables (.csv), daemon logs (.mcap) or files "
                                                "read through --import")
    parser.add_argument("--model", choices=("reduced", "distributed", "wu"), default="reduced",
                        help="model to fit (default: reduced)")
    parser.add_argument("--import", dest="import_desc", help="import description YAML for other layouts")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    """Run ``capstan identify``; returns 0.

    :raises DataFormatError: if a run cannot be read.
    :raises ModelError: if the model cannot be fitted.
    """
    from capstan.models.closure.identification import ModelKind, fit_baseline
    from capstan.models.closure.signals import signals_from_tables
    from capstan.tools.offline.run_inputs import load_runs

    tables = load_runs(args.runs, args.import_desc)
    sig = signals_from_tables(tables)
    fit = fit_baseline(sig, ModelKind.parse(args.model))
    out = {"model": args.model, "params": fit.params, "stderr": fit.stderr, "rmse_Nm": fit.rmse_Nm,
           "max_err_Nm": fit.max_err_Nm, "n_samples": fit.n_samples, **fit.extra,
           "data": [t.source for t in tables],
           "uncertainty": "1-sigma, Gauss-Newton with block-sandwich (autocorrelation-robust) covariance"}
    if args.json:
        print(json.dumps(out, indent=None))
        return 0
    print(f"model: {args.model}   runs: {len(tables)}   samples: {fit.n_samples}")
    for k, v in fit.params.items():
        print(f"  {k:<20} {v:12.6g}  +- {fit.stderr.get(k, float('nan')):.3g}")
    for name, d in fit.extra.items():
        print(f"  [{name}] " + ", ".join(f"{k}={v:.6g}" for k, v in d.items()))
    print(f"fit error: RMSE {fit.rmse_Nm:.4g} Nm, max {fit.max_err_Nm:.4g} Nm (tau_out)")
    return 0
