"""``capstan run --config config/rig.yaml [--duration-s S] [--json]``: the controller daemon.

Runs until SIGTERM/SIGINT (or ``--duration-s``), ramps torque to zero, disables the drive
and closes the log. Exit codes: 0 stopped normally; 2 a start-up or configuration
error (systemd restarts the unit); 3 a latched control fault — the unit does not
restart on its own (``RestartPreventExitStatus=3``): someone has to look at the fault
report first; 4 a device is gone (the drive stopped its heartbeat and did not answer
the disable: unplugged, powered off, or its process killed), named in the fault text.
"""

from __future__ import annotations

import argparse
import json
import logging

from capstan.controller.law.records import FaultBits
from capstan.controller.runtime.daemon import Daemon
from capstan.controller.runtime.config import DaemonConfig
from capstan.models.common.errors import ControlFaultError, UsageError

HELP = "run the 1 kHz controller daemon (rig or simulated devices)"

#: exit code of a latched control fault (no automatic restart)
EXIT_FAULT = 3
#: exit code of a fault with a device gone (``FaultBits.DEVICE_LOST``): a failed rig
EXIT_DEVICE_LOST = 4

log = logging.getLogger("capstan.run")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``capstan run``."""
    parser.add_argument("--config", required=True, help="daemon config YAML (e.g. config/rig.yaml)")
    parser.add_argument("--duration", dest="duration_s", type=float, help=argparse.SUPPRESS)   # deprecated spelling
    parser.add_argument("--duration-s", type=float, default=None, metavar="S",
                        help="stop after S seconds of control (default: run until SIGTERM/SIGINT)")
    parser.add_argument("--json", action="store_true", help="print the run summary as one JSON object")


def run(args: argparse.Namespace) -> int:
    """Run the daemon; returns the exit code.

    :raises CapstanError: on configuration, device or real-time errors (exit code 2).
    """
    if args.duration_s is not None and not args.duration_s > 0:
        raise UsageError(f"--duration-s must be > 0, got {args.duration_s}")
    cfg = DaemonConfig.load(args.config)
    daemon = Daemon(cfg)
    code = 0
    try:
        daemon.run(duration_s=args.duration_s)
    except ControlFaultError as exc:
        log.error("stopped on a fault: %s", exc.reason)
        code = EXIT_DEVICE_LOST if exc.bits & FaultBits.DEVICE_LOST else EXIT_FAULT
    summary = daemon.summary.to_dict()
    if args.json:
        print(json.dumps(summary))
    else:
        t = summary["timing"]
        print(f"cycles {summary['cycles']}, missed {summary['missed']}, faults {len(summary['faults'])}, "
              f"jitter p99.9 {t.get('jitter_p999_us', float('nan')):.0f} us, "
              f"dropped log records {summary['dropped_log_records']}, log {summary['log_path']}")
    return code
