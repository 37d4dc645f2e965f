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

A progress bar is drawn on stderr when the closure takes long. ``--stream`` bounds the
memory (runs read one at a time, the selection on windows of a fixed budget, the final
model scored on every held-out sample); ``--workers N`` runs each run as a task on a local
Dask cluster, ``--scheduler ADDRESS`` on an existing one (docs/closure-at-scale.md). The
outputs are written to a temporary directory beside DIR and each moved into DIR whole.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from typing import TYPE_CHECKING

from capstan.models.common.errors import DataFormatError

if TYPE_CHECKING:
    from capstan.models.closure.pipeline import ClosureResult
    from capstan.tools.offline.closure_stream import StreamedClosure

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
    parser.add_argument("--stream", action="store_true",
                        help="bounded memory: read the runs one at a time, close on windows of a fixed budget, score "
                             "the final model on every held-out sample (docs/closure-at-scale.md)")
    parser.add_argument("--workers", type=int, metavar="N",
                        help="stream with each run a task on a local Dask cluster of N worker processes")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="stream with each run a task on the existing Dask scheduler at ADDRESS (tcp://host:port)")
    parser.add_argument("--train-samples", type=int, default=None,
                        help="streamed: training samples of the windows over all runs (default 400000)")
    parser.add_argument("--test-samples", type=int, default=None,
                        help="streamed: held-out samples of the windows over all runs (default 200000)")


def run(args: argparse.Namespace) -> int:
    """Run ``capstan close``; returns 0.

    :raises DataFormatError: if a run cannot be read or the split is impossible.
    :raises ModelError: if the baseline cannot be fitted.
    """
    from capstan.models.closure.effects import FeatureContext
    from capstan.tools.offline.closure_report import fragment, summary, write_fragment, write_report
    from capstan.tools.offline.closure_stream import replace_files

    if not 0.1 <= args.train_fraction <= 0.9:
        raise DataFormatError(f"--train-fraction must be within [0.1, 0.9], got {args.train_fraction}")
    streamed = None
    if args.stream or args.workers is not None or args.scheduler:
        streamed = _close_streamed(args)
        res, train_names, test_names = streamed.result, streamed.train_names, streamed.test_names
        attributions = streamed.attributions
    else:
        res, train_names, test_names, attributions = _close_in_memory(args)
    summ = summary(res, train_names, test_names, args.model)
    if streamed is not None:
        summ["streamed"] = streamed.summary_keys()
    outdir = Path(args.report)
    ctx = FeatureContext.from_train(res.train, res.baseline)
    frag = fragment(res, args.model, ctx.refs, ctx.q_ref_rad)
    with replace_files(outdir) as tmp:      # each output appears whole, once the closure is done
        write_fragment(frag, tmp / "effects.yaml")
        write_report(res, summ, tmp, attributions)
        (tmp / "closure.json").write_text(json.dumps(summ, indent=1, default=float))
    report = outdir / "report.md"
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
    every = summ.get("streamed", {}).get("every_sample")
    if every:
        print(f"every held-out sample ({every['held_out_samples']}): RMSE {every['baseline_rmse_Nm']:.4g} -> "
              f"{every['final_rmse_Nm']:.4g} Nm, max {every['baseline_max_err_Nm']:.4g} -> "
              f"{every['final_max_err_Nm']:.4g} Nm (the selection ran on "
              f"{summ['streamed']['window_samples']['train']} + {summ['streamed']['window_samples']['test']} "
              "samples of windows)")
    print(f"report: {report}   fragment: {outdir / 'effects.yaml'}")
    return 0


def _close_in_memory(args: argparse.Namespace) -> tuple[ClosureResult, list[str], list[str], list[str]]:
    """The closure with every run in memory: (result, training names, held-out names, attributions).

    :raises DataFormatError: if a run cannot be read or the split is impossible.
    """
    from capstan.models.closure.identification import ModelKind
    from capstan.models.closure.pipeline import close, split_single
    from capstan.models.closure.signals import signals_from_tables
    from capstan.tools.offline.progress import Progress
    from capstan.tools.offline.run_inputs import load_runs

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
    attributions = sorted({str(t.meta["attribution"]) for t in train_t + test_t if "attribution" in t.meta})
    return res, train_names, test_names, attributions


def _close_streamed(args: argparse.Namespace) -> StreamedClosure:
    """The streamed closure (``--stream``, ``--workers N``, ``--scheduler ADDRESS``).

    :raises DataFormatError: if a run cannot be read or the split is impossible.
    :raises UsageError: if the options conflict or the scheduler cannot be reached.
    """
    from capstan.models.common.errors import UsageError
    from capstan.models.closure.identification import ModelKind
    from capstan.models.closure.streaming import TEST_SAMPLES, TRAIN_SAMPLES
    from capstan.tools.offline.closure_stream import DaskMapper, close_streamed, in_process, pieces
    from capstan.tools.offline.progress import Progress

    if args.workers is not None and args.scheduler:
        raise UsageError("give --workers N (a local cluster) or --scheduler ADDRESS (an existing one), not both")
    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers must be >= 1, got {args.workers}")
    for key in ("train_samples", "test_samples"):
        val = getattr(args, key)
        if val is not None and val < 1000:
            raise UsageError(f"--{key.replace('_', '-')} must be >= 1000, got {val}")
    train, test = pieces(args.train, args.test, args.import_desc, args.train_fraction)
    mapper = DaskMapper(args.workers, args.scheduler) if args.workers is not None or args.scheduler else None
    bar = Progress("close", enabled=args.progress)
    try:
        out = close_streamed(train, test, mapper or in_process, ModelKind.parse(args.model),
                             args.baseline == "dynamic", args.train_samples or TRAIN_SAMPLES,
                             args.test_samples or TEST_SAMPLES, progress=lambda d, t, _l: bar.update(d, t))
    finally:
        bar.done()
        if mapper is not None:
            mapper.close()
    return out
