"""``capstan experiment paper``: reproduce the paper's Figs. 6-11 and 13 on the simulated rig.

    capstan experiment paper --out DIR [--quick] [--seed N] [--only fig6,fig9_10,...]

Runs the figure builders of :mod:`capstan.tools.experiments.paper.figs_stiffness` (Figs. 6, 7),
:mod:`capstan.tools.experiments.paper.figs_profiles` (Fig. 8), :mod:`capstan.tools.experiments.paper.figs_prediction` (Figs. 9-10),
:mod:`capstan.tools.experiments.paper.figs_models` (Fig. 11)
and :mod:`capstan.tools.experiments.paper.figs_interaction` (Fig. 13) on "measured" runs of the full distributed
plant with sensor noise, times each one, and writes into ``DIR``:

* ``report.md``: per figure a table *quantity | paper | ours | ratio | note* with the PNGs
  embedded, a wall-time column per figure, and the recommendation derived from this run's
  numbers (:mod:`capstan.tools.experiments.paper.recommend`);
* ``results.json``: the settings, every figure's rows, claims and data, the recommendation and
  the fingerprint of the sources (:mod:`capstan.tools.experiments.paper.fingerprint`);
* the PNGs.

Figs. 9-10 and 11 share their measured runs (:class:`capstan.tools.experiments.paper.run_cache.RunCache`);
the first of them to run pays for the simulation of the shared runs.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import time
from pathlib import Path
from typing import Any, Callable

from capstan.models.common.errors import CapstanError, ConfigError
from capstan.tools.experiments.paper.common import Settings

log = logging.getLogger(__name__)

HELP = "reproduce the paper's figures on the simulated rig (report.md, results.json, PNGs)"

#: figure keys in run order
FIGURES: tuple[str, ...] = ("fig6", "fig7", "fig8", "fig9_10", "fig11", "fig13")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options ``--out`` (required), ``--quick``, ``--seed``, ``--only``."""
    parser.add_argument("--out", type=Path, required=True, help="output directory (created if missing)")
    parser.add_argument("--quick", action="store_true",
                        help="coarse grids (6 routing groups, N in 1,2,4,10,20, 30-node plant) for CI")
    parser.add_argument("--seed", type=int, default=0, help="sensor-noise / unmodelled-effects seed")
    parser.add_argument("--only", type=str, default=None,
                        help=f"comma-separated subset of {','.join(FIGURES)} (default: all)")


def parse_only(text: str | None) -> tuple[str, ...]:
    """The figures selected by ``--only`` in run order (all when ``text`` is None or empty).

    :raises ConfigError: on an unknown figure key.
    """
    if not text:
        return FIGURES
    wanted = {t.strip() for t in text.split(",") if t.strip()}
    unknown = sorted(wanted - set(FIGURES))
    if unknown:
        raise ConfigError("experiment.paper.only", f"unknown figure(s) {unknown}; choose from {list(FIGURES)}")
    return tuple(f for f in FIGURES if f in wanted)


def _builders(settings: Settings) -> dict[str, Callable[[Path], dict[str, Any]]]:
    """Figure key -> builder taking the output directory (imports are lazy: matplotlib, Numba)."""
    from capstan.tools.experiments.paper import figs_interaction as inter
    from capstan.tools.experiments.paper import figs_models as models
    from capstan.tools.experiments.paper import figs_prediction as pred
    from capstan.tools.experiments.paper import figs_profiles as prof
    from capstan.tools.experiments.paper import figs_stiffness as stiff
    from capstan.tools.experiments.paper.run_cache import RunCache

    cache = RunCache(settings)
    return {
        "fig6": lambda d: stiff.fig6(settings, d),
        "fig7": lambda d: stiff.fig7(settings, d),
        "fig8": lambda d: prof.fig8(settings, d),
        "fig9_10": lambda d: pred.fig9_10(settings, d, cache),
        "fig11": lambda d: models.fig11(settings, d, cache),
        "fig13": lambda d: inter.fig13(settings, d),
    }


def run_paper(out_dir: Path, settings: Settings, only: tuple[str, ...] = FIGURES) -> dict[str, Any]:
    """Run the selected figure builders, write ``report.md``, ``results.json`` and the PNGs.

    A figure whose simulation leaves the model's range (any :class:`CapstanError`) is recorded
    as failed with its message and the others still run; other exceptions propagate.

    :returns: the results document (as written to ``results.json``).
    :raises OSError: if ``out_dir`` cannot be written.
    :raises CapstanError: if the start-up runs (:func:`_warm_up`) fail.
    """
    from capstan.tools.experiments.paper.fingerprint import source_fingerprint
    from capstan.tools.experiments.paper.recommend import recommend
    from capstan.tools.experiments.paper.report import render_report

    out_dir.mkdir(parents=True, exist_ok=True)
    builders = _builders(settings)
    figures: dict[str, Any] = {}
    failed: dict[str, str] = {}
    t_start = time.perf_counter()
    digest, n_files = source_fingerprint()                # the sources as they were when the run started
    startup_s = _warm_up(settings, only)
    log.info("start-up (compiled kernels loaded): %.1f s", startup_s)
    for key in only:
        log.info("%s: running (%s settings)", key, "quick" if settings.quick else "full")
        t0 = time.perf_counter()
        try:
            res = builders[key](out_dir)
        except CapstanError as exc:
            failed[key] = f"{type(exc).__name__}: {exc}"
            log.error("%s failed: %s", key, failed[key])
            continue
        res["wall_s"] = time.perf_counter() - t0          # includes shared runs simulated on first use
        figures[key] = res
        log.info("%s: %d rows, %d figure(s), %.1f s", key, len(res["rows"]), len(res["figures"]), res["wall_s"])
    doc: dict[str, Any] = {
        "source_fingerprint": {"sha256": digest, "files": n_files},
        "settings": dataclasses.asdict(settings),
        "figures_requested": list(only),
        "figures": figures,
        "failed": failed,
        "recommendation": recommend(figures),
        "startup_s": startup_s,
        "total_wall_s": time.perf_counter() - t_start,
    }
    doc = _json_safe(doc)
    (out_dir / "results.json").write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    (out_dir / "report.md").write_text(render_report(doc), encoding="utf-8")
    return doc


def _warm_up(settings: Settings, only: tuple[str, ...]) -> float:
    """Load (or compile) the Numba kernels on tiny runs so the first figure's wall time is its own.

    :returns: the wall time spent [s].
    :raises CapstanError: if a tiny run fails (a broken install, not a figure's result).
    """
    t0 = time.perf_counter()
    from capstan.tools.experiments.paper.common import group_routing, simulate_plant, sine

    if any(k != "fig13" for k in only):
        simulate_plant(group_routing(9), sine(1.0), settings, n_nodes=2, duration_s=0.05)
    if "fig13" in only:
        from capstan.tools.experiments.interaction import CONDITIONS
        from capstan.tools.experiments.paper.figs_interaction import interaction_series

        interaction_series(next(iter(CONDITIONS)), "ldo", True, "reference", 0.02, settings.seed)
    return time.perf_counter() - t0


def _json_safe(x: Any) -> Any:
    """Plain JSON types; non-finite floats become None (strict JSON has no NaN)."""
    if isinstance(x, dict):
        return {str(k): _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if hasattr(x, "tolist"):                              # numpy arrays and scalars
        return _json_safe(x.tolist())
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    return x


def run(args: argparse.Namespace) -> int:
    """Run the paper experiment; prints a short summary; returns 0, or 1 if a figure failed.

    :raises ConfigError: on a bad ``--only``.
    """
    only = parse_only(args.only)
    settings = Settings.quick_settings() if args.quick else Settings()
    settings = dataclasses.replace(settings, seed=args.seed)
    doc = run_paper(Path(args.out), settings, only)
    for key, res in doc["figures"].items():
        print(f"{key:<8} {res['wall_s']:7.1f} s  {len(res['rows']):3d} rows  {', '.join(res['figures'])}")
    for key, msg in doc["failed"].items():
        print(f"{key:<8} FAILED  {msg}")
    print(f"wrote {Path(args.out) / 'report.md'} and results.json in {doc['total_wall_s']:.0f} s")
    return 1 if doc["failed"] else 0
