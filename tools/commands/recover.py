"""``capstan recover LOG.mcap [--out FILE]``: a log cut off by a crash as a valid file.

A daemon killed together with its log writer leaves a file without summary or footer;
``mcap``'s indexed reader and Foxglove refuse it. This keeps everything that can be
read by streaming (every complete chunk, byte for byte) and writes the indexes and the
footer (:func:`capstan.controller.log.recover.recover_log`). Without ``--out`` the file
is replaced, only once the rewrite is complete.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HELP = "rewrite a log cut off by a crash into a valid indexed file"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``capstan recover``."""
    parser.add_argument("log", type=Path, help="the cut-off MCAP log")
    parser.add_argument("--out", type=Path, help="write here instead of replacing LOG")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace) -> int:
    """Run ``capstan recover``; returns 0.

    :raises DataFormatError: if the file is missing or not MCAP at all.
    """
    from capstan.controller.log.recover import recover_log

    res = recover_log(args.log, args.out)
    if args.json:
        print(json.dumps({"path": str(res.path), "was_complete": res.was_complete, "chunks": res.chunks,
                          "messages": res.messages, "bytes_dropped": res.bytes_dropped,
                          "stop_reason": res.stop_reason}))
    elif res.was_complete:
        print(f"{args.log}: complete (has a footer); nothing to recover"
              + (f", copied to {res.path}" if args.out else ""))
    else:
        print(f"{res.path}: {res.chunks} chunks, {res.messages} messages kept; "
              f"{res.bytes_dropped} bytes cut off ({res.stop_reason})")
    return 0
