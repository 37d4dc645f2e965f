"""``capstan export LOG.mcap --out RUN.csv``: a daemon log as a measurement table.

The mapping of cycle records onto the standard columns is
:func:`capstan.tools.offline.log_table.records_to_table`; every record field is also
written as an extra column under its own name (units in the sidecar).
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path


from capstan.tools.offline.log_table import records_to_table

HELP = "export an MCAP log to the measurement table (CSV + YAML sidecar)"
_log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``capstan export``."""
    parser.add_argument("log", nargs="+", help="capstan MCAP log (several = one rotated run, in order)")
    parser.add_argument("--out", required=True, help="output CSV (sidecar written next to it)")
    parser.add_argument("--precision", type=int, default=12, help="significant digits (default 12)")
    parser.add_argument("--json", action="store_true", help="print the result as one JSON object")


def run(args: argparse.Namespace) -> int:
    """Run ``capstan export``; returns 0.

    :raises DataFormatError: if the log cannot be read or mapped.
    """
    from capstan.controller.log.reader import read_logs
    from capstan.tools.offline.archive import read_any
    from capstan.tools.offline.progress import Progress
    from capstan.models.common.measurement_table import write_table

    paths = [Path(p) for p in args.log]
    big = sum(p.stat().st_size for p in paths if p.exists()) > 20_000_000
    bar = Progress("read", enabled=big and len(paths) == 1)
    data = read_any(paths[0], bar.update) if len(paths) == 1 else read_logs(paths)
    bar.done()
    table = records_to_table(data.records, data.config, ", ".join(str(p) for p in paths))
    if data.truncated:
        table.meta["truncated"] = True
    out = write_table(table, args.out, precision=args.precision)
    if args.json:
        print(json.dumps({"out": str(out), "sidecar": str(out.with_suffix(".yaml")), "rows": len(table),
                          "columns": list(table.columns), "truncated": bool(data.truncated)}))
    else:
        print(f"{out}: {len(table)} rows, {len(table.columns)} columns (sidecar {out.with_suffix('.yaml')})")
    return 0
