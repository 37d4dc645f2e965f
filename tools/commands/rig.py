"""``capstan rig bringup --config START.yaml --out TUNED.yaml [--json] [--fix] [--plant PLANT.yaml]``.

Bring-up of a rig: check (directions, channel order, IMU axis and sign) -> calibrate (load-cell
zero and scale against the drive's torque, gyro bias) -> identify (held and free runs) ->
tune (gains on the identified plant with the loop model), then TUNED.yaml written at once
(docs/bring-up.md). With ``--plant`` the rig is the simulated one served from that plant
file for the duration: START's bus and ports are replaced by the served rig's endpoints (and
written as ``auto`` into TUNED.yaml, for ``capstan hil --plant``); the workflow sees only
its devices, never the plant file's values.

Exit codes: 0 tuned config written; 2 bad START config or options; 3 a step refused
(mismatch, limit, lost device, fit or tuning failed): torque zero, the reason in one line,
no output file.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
from pathlib import Path
from typing import Callable

from capstan.tools.hil.serve import ServedRig, load_plant
from capstan.tools.rig.verify_step import VERIFY_S
from capstan.tools.rig.start_config import RigStart
from capstan.models.common.config_tools import load_yaml
from capstan.models.common.errors import DriverError
from capstan.tools.offline.shipped import config_path
from capstan.tools.rig.workflow import BringupReport, bringup

HELP = "rig bring-up: check, calibrate, identify, tune -> a tuned config (capstan rig bringup)"

log = logging.getLogger("capstan.rig")

EXIT_REFUSED = 3


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``capstan rig``."""
    sub = parser.add_subparsers(dest="action", required=True)
    b = sub.add_parser("bringup", help="check -> calibrate -> identify -> tune, write a tuned daemon config")
    b.add_argument("--config", required=True, metavar="START.yaml", help="devices, drawing, reference, limits")
    b.add_argument("--out", required=True, metavar="TUNED.yaml", help="the tuned daemon config (written at the end)")
    b.add_argument("--plant", default=None, metavar="PLANT.yaml",
                   help="bring up the simulated rig served from this plant file (START's ports 'auto')")
    b.add_argument("--fix", action="store_true",
                   help="write the corrections a config can carry (IMU sign, load-cell scales) instead of stopping")
    b.add_argument("--json", action="store_true", help="print the report as one JSON object")


def _ask(prompt: str) -> None:
    print(prompt, file=sys.stderr, flush=True)
    input()


def _ask_to_move_the_link() -> None:
    _ask(f"The tuned loop runs for {VERIFY_S:.0f} s next: take the link and move it gently through "
         f"its range while it runs, then press Enter to start")


def _interactive_hold() -> Callable[[bool], None] | None:
    if not sys.stdin.isatty():
        return None

    def hold(on: bool) -> None:
        _ask("Clamp the link near hanging (against a stop), keep clear, then press Enter" if on
             else "Release the link so it hangs free, keep clear, then press Enter")
    return hold


def run(args: argparse.Namespace) -> int:
    """Run the bring-up; returns the exit code.

    :raises ConfigError: on an invalid START config or plant file (exit code 2).
    """
    start = RigStart.load(args.config)
    out = Path(args.out)
    served = None
    rep = BringupReport()
    try:
        if args.plant is not None:
            served = ServedRig(load_plant(args.plant))
            ports = served.start()
            tuned_start = start.with_ports({"channel": "auto", "imu_port": "auto", "load_cells_port": "auto"})
            start = start.with_ports(ports)
            pid = int(ports["pid"])

            def hold(on: bool) -> None:
                os.kill(pid, signal.SIGUSR1 if on else signal.SIGUSR2)
            hold_link: Callable[[bool], None] | None = hold
        else:
            hold_link = _interactive_hold()
            tuned_start = start
        # the controller structure the tuning scales: the shipped rig's, or on the simulated
        # rig the shipped HIL config's (its staleness limits allow for a shared VM's stalls)
        base = load_yaml(config_path("hil.yaml" if args.plant is not None else "rig.yaml"))["controller"]
        at_rig = args.plant is None and sys.stdin.isatty()
        rep = bringup(start, out, fix=args.fix, hold_link=hold_link, tuned_start=tuned_start, base_controller=base,
                      before_verify=_ask_to_move_the_link if at_rig else None)
    except DriverError as exc:                   # the served rig did not come up: nothing moved
        rep.step, rep.reason = "check", f"{type(exc).__name__}: {exc}"
    finally:
        if served is not None:
            served.close()
    if args.json:
        print(json.dumps(rep.to_dict(), default=str))
    elif rep.ok:
        print(f"tuned config written: {rep.out} ({rep.wall_s:.0f} s; logs: {', '.join(rep.logs)})")
    else:
        print(f"bring-up stopped in {rep.step}: {rep.reason}")
    return 0 if rep.ok else EXIT_REFUSED
