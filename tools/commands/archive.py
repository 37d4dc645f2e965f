"""``capstan archive LOG.mcap [--out FILE]``: the lossless columnar form of a live log.

About a quarter of the live size (:mod:`capstan.tools.offline.archive`: one message per
second of cycles, step outputs recomputed where the replay reproduces them bit for bit,
events and stats as they are). The archive is read back and compared with the live
log field by field before the command reports success; ``replay``, ``export`` and
``close`` read both forms.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HELP = "rewrite a live log as a lossless columnar archive (about a quarter of the size)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``capstan archive``."""
    parser.add_argument("log", type=Path, help="live capstan MCAP log")
    parser.add_argument("--out", type=Path, help="archive file (default: LOG with .archive.mcap)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace) -> int:
    """Run ``capstan archive``; returns 0.

    :raises DataFormatError: if the log cannot be read or the archive does not read back equal.
    """
    from capstan.tools.offline.archive import write_archive
    from capstan.tools.offline.progress import Progress

    out = args.out or args.log.with_name(args.log.name.removesuffix(".mcap") + ".archive.mcap")
    bar = Progress("read  ", enabled=args.log.stat().st_size > 20_000_000 if args.log.exists() else False)
    res = write_archive(args.log, out, bar.update)
    bar.done()
    per_h = 3600.0 / res.duration_s / 1e6 if res.duration_s > 0 else float("nan")
    report = {"archive": str(res.path), "cycles": res.cycles, "duration_s": res.duration_s,
              "live_bytes": res.source_bytes, "archive_bytes": res.archive_bytes,
              "live_MB_per_hour": res.source_bytes * per_h, "archive_MB_per_hour": res.archive_bytes * per_h,
              "recomputed_fields": list(res.recomputed), "verified_bit_exact": True}
    if args.json:
        print(json.dumps(report))
    else:
        print(f"{res.path}: {res.cycles} cycles, {res.archive_bytes} B "
              f"({report['archive_MB_per_hour']:.0f} MB/hour; live {report['live_MB_per_hour']:.0f}), "
              f"read back bit for bit; recomputed on reading: {', '.join(res.recomputed) or 'none'}")
    return 0
