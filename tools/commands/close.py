"""``capstan close TRAIN... --test HELDOUT... --report DIR [--json]``: close the model
loop with measured data (see :mod:`capstan.models.closure.pipeline`).

1. fit the baseline on the training runs only: by default the reduced model simulated
   through every sample with friction as a state, driven by the boundary signals the runs
   carry (the form and the predicted channel are stated; channels tied to that channel
   are excluded from the candidates); ``--baseline static`` for the friction-on-velocity
   regression (it is fitted in both cases: the controller's feedforward map);
2. predict the held-out runs; residual = measured - predicted. With a single run and
   no ``--test``, the run is split into a contiguous head (first 70 %, training) and
   tail (last 30 %, held out) -- never random samples;
3. trace the residual to signals; 4./5. fit every catalogued effect (and the empirical
   fallbacks) on training data, score on held-out data, select greedily by block
   bootstrap; 6. write ``DIR/report.md`` + PNGs and ``DIR/closure.json``; 7. write the
   augmented model as ``DIR/effects.yaml`` (controller config fragment).

A progress bar is drawn on stderr when the closure takes long.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from capstan.models.common.errors import DataFormatError

HELP = "close the model loop: residual -> missing effect -> before/after report"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``capstan close``."""
    parser.add_argument("train", nargs="+", help="training runs (.csv tables, .mcap logs, or --import layouts)")
    parser.add_argument("--test", action="append", default=[], metavar="RUN",
                        help="a held-out run; repeat for several (none: split a single run 70/30)")
    parser.add_argument("--report", required=True, help="report directory (Markdown + PNG + JSON + fragment)")
    parser.add_argument("--model", choices=("reduced", "wu"), default="reduced", help="baseline model")
    parser.add_argument("--baseline", choices=("dynamic", "static"), default="dynamic",
                        help="dynamic: the reduced model simulated through each run, friction as a state, effects "
                             "inside it (default); static: the friction-on-measured-velocity regression of tau_out")
    parser.add_argument("--import", dest="import_desc", help="import description YAML for other layouts")
    parser.add_argument("--train-fraction", type=float, default=0.7,
                        help="single-run split: contiguous training head fraction (default 0.7)")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=True,
                        help="show a progress bar (default: yes)")


def run(args: argparse.Namespace) -> int:
    """Run ``capstan close``; returns 0.

    :raises DataFormatError: if a run cannot be read or the split is impossible.
    :raises ModelError: if the baseline cannot be fitted.
    """
    from capstan.models.closure.pipeline import close, split_single
    from capstan.models.closure.effects import FeatureContext
    from capstan.models.closure.identification import ModelKind
    from capstan.models.closure.signals import signals_from_tables
    from capstan.tools.offline.closure_report import fragment, summary, write_fragment, write_report
    from capstan.tools.offline.progress import Progress
    from capstan.tools.offline.run_inputs import load_runs

    if not 0.1 <= args.train_fraction <= 0.9:
        raise DataFormatError(f"--train-fraction must be within [0.1, 0.9], got {args.train_fraction}")
    train_t = load_runs(args.train, args.import_desc)
    test_t = load_runs(args.test, args.import_desc) if args.test else []
    sig = signals_from_tables(train_t + test_t)
    if test_t:
        train = sig.take(sig.run_id < len(train_t))
        test = sig.take(sig.run_id >= len(train_t))
        train_names, test_names = [t.source for t in train_t], [t.source for t in test_t]
    else:
        if len(train_t) != 1:
            raise DataFormatError("without --test give exactly one run (it is split into contiguous blocks), "
                                  "or name held-out runs with --test")
        train, test = split_single(sig, args.train_fraction)
        n = len(sig)
        k = int(round(args.train_fraction * n))
        src = train_t[0].source
        train_names = [f"{src} [t {sig.t_s[0]:.3f}-{sig.t_s[k - 1]:.3f} s]"]
        test_names = [f"{src} [t {sig.t_s[k]:.3f}-{sig.t_s[-1]:.3f} s]"]
    bar = Progress("close", enabled=args.progress)
    res = close(train, test, ModelKind.parse(args.model), progress=lambda d, t, _l: bar.update(d, t),
                dynamic=args.baseline == "dynamic")
    bar.done()
    summ = summary(res, train_names, test_names, args.model)
    outdir = Path(args.report)
    outdir.mkdir(parents=True, exist_ok=True)
    ctx = FeatureContext.from_train(res.train, res.baseline)
    frag = fragment(res, args.model, ctx.refs, ctx.q_ref_rad)
    write_fragment(frag, outdir / "effects.yaml")
    attributions = sorted({str(t.meta["attribution"]) for t in train_t + test_t if "attribution" in t.meta})
    report = write_report(res, summ, outdir, attributions)
    (outdir / "closure.json").write_text(json.dumps(summ, indent=1, default=float))
    if args.json:
        print(json.dumps(summ, default=float))
        return 0
    b = summ["baseline"]
    print(f"baseline ({args.model}, {args.baseline}) predicts {b['target']} from {', '.join(b['driving'])}: "
          f"held-out RMSE {b['rmse_Nm']:.4g} Nm, max {b['max_err_Nm']:.4g} Nm, skill {b['skill']:.3f}")
    for name in b.get("at_bound", []):
        print(f"  ! parameter {name} = {b['params'][name]:.4g} ends at a bound of its physical domain")
    for name, why in b.get("implausible", {}).items():
        print(f"  ! parameter {name} implausible: {why}")
    for w in b.get("warnings", []):
        print(f"  ! {w}")
    for e in summ.get("excluded", []):
        print(f"  - {e['signal']} is not a candidate: {e['reason']}")
    for s in summ["selected"]:
        print(f"  + {s['effect']} ({', '.join(s['depends_on'])}): {100 * s['improvement']:.1f} % lower RMSE")
    if not summ["selected"]:
        print("  no effect improves the held-out prediction significantly")
    for u in summ.get("unexplained", []):
        print(f"  ! {u}")
    print(f"final held-out RMSE {summ['final']['rmse_Nm']:.4g} Nm, max {summ['final']['max_err_Nm']:.4g} Nm, "
          f"skill {summ['final']['skill']:.3f}")
    if "elastic" in summ:
        e = summ["elastic"]
        print(f"elastic path RMSE {e['baseline_rmse_Nm']:.4g} -> {e['final_rmse_Nm']:.4g} Nm")
    print(f"report: {report}   fragment: {outdir / 'effects.yaml'}")
    return 0
