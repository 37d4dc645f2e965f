"""The ``capstan`` command line.

Subcommands live in their own modules and are imported lazily, so ``capstan --help``
does not compile Numba code. Each command module provides::

    HELP: str                                   # one line for the command list
    def add_arguments(parser: argparse.ArgumentParser) -> None
    def run(args: argparse.Namespace) -> int     # exit code

The conventions every subcommand follows (``tests/test_cli_convention.py`` walks every
``--help``): options spelled in lower-case words joined by ``-`` with the unit last where there is
one (``--duration-s``); ``-v/--verbose`` accepted everywhere, also after a sub-subcommand;
``--json`` on every command that reports a result; an option takes one value (a list is the
option repeated), so it cannot swallow the positionals; an on/off option is a ``--x/--no-x``
pair. Library errors (:class:`capstan.models.common.errors.CapstanError`) become one plain line
on stderr, ``capstan CMD: what: why``, and exit code 2; anything else is a bug and keeps its
traceback.
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
    "config": "list or print the shipped configuration files, or the reference of every key",
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


def build_parser(name: str) -> argparse.ArgumentParser:
    """The argument parser of subcommand ``name``, with ``-v/--verbose`` on it and on every
    sub-subcommand (``capstan experiment loop -v``)."""
    module = importlib.import_module(COMMANDS[name])
    parser = argparse.ArgumentParser(prog=f"capstan {name}", description=getattr(module, "HELP", None))
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    module.add_arguments(parser)
    for action in parser._actions:                    # argparse keeps sub-parsers only here
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                if not any("--verbose" in a.option_strings for a in sub._actions):
                    sub.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS,
                                     help="debug logging")
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
    parser = build_parser(name)
    args = parser.parse_args(argv[1:])
    logging.basicConfig(
        level=logging.DEBUG if (verbose or args.verbose) else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        return int(module.run(args) or 0)
    except CapstanError as exc:
        sys.stderr.write(f"capstan {name}: {exc}\n")
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
