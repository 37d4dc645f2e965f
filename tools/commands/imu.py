"""``capstan imu setup PORT [--baudrate BD] [--config YAML] [--json]``: bring up a new MTi.

Finds the device on ``PORT`` (the running rate first, then the standard rates, 115200 Bd
- the factory default - first), stores the running rate in it (SetBaudrate, Reset),
sets the output configuration the controller needs and checks it by read-back, and
prints the rate it found, the rate it set and the configuration read back. The device
keeps both over a power cycle, so the daemon then finds it at the first try.

Settings come from the ``imu`` section of ``--config`` if given (``backend`` dropped,
as drivers/registry.py does); ``PORT`` and ``--baudrate`` override it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

HELP = "IMU bring-up: find a (new) Xsens MTi's baud rate, set the running rate and output, verify"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``capstan imu``."""
    sub = parser.add_subparsers(dest="action", required=True)
    setup = sub.add_parser("setup", help="find the device's rate, store the running rate and output configuration")
    setup.add_argument("port", help="serial device, e.g. /dev/ttyUSB0")
    setup.add_argument("--baudrate", type=int, default=None, help="running rate to store [Bd] (default: config or 921600)")
    setup.add_argument("--config", type=Path, default=None, help="YAML with an 'imu' section (rate, output, timeouts)")
    setup.add_argument("--json", action="store_true", help="one JSON object instead of text")


def _settings(args: argparse.Namespace) -> dict[str, Any]:
    cfg: dict[str, Any] = {}
    if args.config is not None:
        from capstan.models.common.config_tools import load_yaml, section

        cfg = {k: v for k, v in section(load_yaml(args.config), "imu").items() if k != "backend"}
    cfg["port"] = args.port
    cfg["baud_search"] = True
    if args.baudrate is not None:
        cfg["baudrate"] = args.baudrate
    return cfg


def run(args: argparse.Namespace) -> int:
    """Run the bring-up; exit code 0.

    :raises ConfigError: on a bad ``imu`` section or rate.
    :raises DeviceTimeoutError: if the device answers at no rate.
    :raises ProtocolError: if it refuses the configuration or the read-back lacks an item.
    :raises DriverError: if the port cannot be opened.
    """
    from capstan.drivers.serial.xsens import XsensImu
    from capstan.drivers.serial.xsens_protocol import FREQ_EVERY_PACKET, xdi_name

    imu = XsensImu.from_config(_settings(args))
    try:
        imu.start()
    finally:
        imu.close()
    c = imu.config
    items = [{"item": xdi_name(x), "rate_hz": None if f in (0, FREQ_EVERY_PACKET) else f}
             for x, f in imu.output_readback]
    if args.json:
        sys.stdout.write(json.dumps({"port": c.port, "found_baudrate": imu.found_baudrate,
                                     "baudrate": c.baudrate, "output_configuration": items}) + "\n")
        return 0
    moved = (f"switched to {c.baudrate} Bd (stored in the device)" if imu.found_baudrate != c.baudrate
             else "already at the running rate")
    sys.stdout.write(f"MTi on {c.port}: found at {imu.found_baudrate} Bd, {moved}\n")
    sys.stdout.write("output configuration read back and checked:\n")
    for it in items:
        rate = "every packet" if it["rate_hz"] is None else f"{it['rate_hz']} Hz"
        sys.stdout.write(f"  {it['item']:<28} {rate}\n")
    sys.stdout.write(f"set imu.baudrate: {c.baudrate} and imu.port: {c.port} in the rig config\n")
    return 0
