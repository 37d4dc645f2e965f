"""``capstan simulate SCENARIO.yaml --out RUN.csv [--plot]``: run a testbed scenario on the
distributed plant and write the measurement table (+ ``.yaml`` sidecar)."""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

from capstan.models.common.measurement_table import write_table
from capstan.tools.offline.scenario import Scenario, run_scenario

HELP = "Run a testbed scenario on the distributed plant and write a measurement table."

log = logging.getLogger("capstan.simulate")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``capstan simulate``."""
    parser.add_argument("scenario", help="scenario YAML (docs/simulation.md)")
    parser.add_argument("--out", required=True, help="measurement table CSV to write (sidecar .yaml beside it)")
    parser.add_argument("--plot", action=argparse.BooleanOptionalAction, default=False,
                        help="write tau_in-tau_out and tau_in-deflection loops as PNG (default: no)")
    parser.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def run(args: argparse.Namespace) -> int:
    """Run the scenario; returns 0 on success.

    :raises ConfigError: bad scenario.
    :raises OperatingRangeError: the scenario leaves the model's range (cable slack).
    """
    sc = Scenario.load(args.scenario)
    result = run_scenario(sc)
    out = write_table(result.table, args.out)
    plots = []
    if args.plot:
        plots = [str(p) for p in _plots(result.table, Path(args.out), sc.name)]
    rt = sc.duration_s / result.wall_s if result.wall_s > 0 else float("inf")
    summary = {
        "scenario": sc.name,
        "rows": len(result.table),
        "duration_s": sc.duration_s,
        "wall_s": round(result.wall_s, 3),
        "realtime_factor": round(rt, 1),
        "n_nodes": result.table.meta["n_nodes"],
        "theta_total_rad": round(result.table.meta["theta_total_rad"], 4),
        "T0_eq_N": round(result.table.meta["T0_eq_N"], 3),
        "table": str(out),
        "plots": plots,
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"{sc.name}: {summary['rows']} rows, {sc.duration_s:g} s simulated in {result.wall_s:.2f} s "
              f"({rt:.0f}x real time), N = {summary['n_nodes']}, theta = {summary['theta_total_rad']} rad, "
              f"T0_eq = {summary['T0_eq_N']} N")
        print(f"wrote {out} and {out.with_suffix('.yaml')}")
        for p in plots:
            print(f"wrote {p}")
    return 0


def _plots(table, out: Path, name: str) -> list[Path]:
    from capstan.tools.offline.plots import hysteresis_plots

    return hysteresis_plots(table, out.with_suffix(""), name)
