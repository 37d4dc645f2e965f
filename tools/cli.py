"""The ``capstan`` command line.

Subcommands live in their own modules and are imported lazily, so ``capstan --help``
does not compile Numba code. Each command module provides::

    HELP: str                                   # one line for the command list
    def add_arguments(parser: argparse.ArgumentParser) -> None
    def run(args: argparse.Namespace) -> int     # exit code

Library errors (:class:`capstan.models.common.errors.CapstanError`) become a one-line message on
stderr and exit code 2; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from typing import Sequence

from capstan.models.common.errors import CapstanError

#: command name -> module implementing it
COMMANDS: dict[str, str] = {
    "simulate": "capstan.tools.commands.simulate",
    "run": "capstan.tools.commands.run",
    "hil": "capstan.tools.commands.hil",
    "replay": "capstan.tools.commands.replay",
    "export": "capstan.tools.commands.export",
    "decode": "capstan.tools.commands.decode",
    "imu": "capstan.tools.commands.imu",
    "identify": "capstan.tools.commands.identify",
    "close": "capstan.tools.commands.close",
    "experiment": "capstan.tools.commands.experiment",
    "config": "capstan.tools.commands.config",
    "recover": "capstan.tools.commands.recover",
    "archive": "capstan.tools.commands.archive",
    "rig": "capstan.tools.commands.rig",
}

_SUMMARIES: dict[str, str] = {
    "simulate": "run a testbed scenario on the distributed plant, write a measurement table",
    "run": "run the 1 kHz controller daemon (rig or simulated devices)",
    "hil": "hardware-in-the-loop: simulated rig in its own process + the daemon unchanged",
    "replay": "re-run the controller on a logged MCAP file",
    "export": "export an MCAP log to the measurement table",
    "decode": "decode a raw serial capture (xsens | loadcell)",
    "imu": "IMU bring-up: capstan imu setup PORT finds and sets a new MTi's baud rate",
    "identify": "fit model parameters to measured runs",
    "close": "close the model loop: residual -> missing effect -> before/after report",
    "experiment": "experiments: interaction (Fig. 13), paper (reproduce the paper)",
    "config": "list or print the shipped configuration files",
    "recover": "rewrite a log cut off by a crash into a valid indexed file",
    "archive": "rewrite a live log as a lossless columnar archive",
    "rig": "rig bring-up: check, calibrate, identify, tune -> a tuned config",
}


def _top_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="capstan",
        description="Friction-compensation controller for cable-driven joints.",
        epilog="commands:\n" + "\n".join(f"  {k:<11} {v}" for k, v in _SUMMARIES.items()),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("command", choices=sorted(COMMANDS), help="command to run")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``capstan`` console script; returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    verbose = False
    while argv and argv[0] in ("-v", "--verbose"):
        verbose = True
        argv.pop(0)
    if not argv or argv[0] not in COMMANDS:
        _top_parser().parse_args(argv or ["--help"])
        return 2
    name = argv[0]
    module = importlib.import_module(COMMANDS[name])
    parser = argparse.ArgumentParser(prog=f"capstan {name}", description=getattr(module, "HELP", None))
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    module.add_arguments(parser)
    args = parser.parse_args(argv[1:])
    logging.basicConfig(
        level=logging.DEBUG if (verbose or args.verbose) else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        return int(module.run(args) or 0)
    except CapstanError as exc:
        logging.getLogger("capstan").error("%s: %s", type(exc).__name__, exc)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
