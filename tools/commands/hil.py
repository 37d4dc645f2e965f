"""``capstan hil [--config config/hil.yaml] [--plant PLANT.yaml] --duration-s S [--json]``: hardware-in-the-loop
run; ``capstan hil --serve --plant PLANT.yaml``: the simulated rig alone.

Starts the simulated rig in its own process (:mod:`capstan.tools.hil.plant`: plant in real
time, simulated drive on a fresh ``capstan_unix`` bus, IMU and load cells on pty
pairs), points the config's ``auto`` channel/ports at it and runs the daemon unchanged
for ``S`` seconds of control, then ramps down and prints a summary — with ``--json``
one object: cycles, missed, period jitter p50/p99/p99.9/max [µs], faults, dropped log
records, log path (plus the plant's and the processes' CPU figures; under ``plant``
the simulated rig's statistics, with ``hand`` the interaction torque of ``hil.hand`` and
``effects`` the effects injected into the plant).

With ``--plant`` the simulated rig is the plant file's (:mod:`capstan.tools.hil.serve`: the
``hil.plant`` keys plus the devices' ``sensors``) and its devices are the served hardware, not
the config's device sections: the daemon meets the rig as it would a real one. ``--serve``
runs only that rig, prints its device endpoints as one JSON line
``{"channel", "imu_port", "load_cells_port", "pid"}`` and runs until SIGINT/SIGTERM.

Exit codes as ``capstan run`` (0 ok, 2 start-up error, 3 control fault, 4 device loss);
4 also if the simulated rig failed (e.g. cable slack) or its process died.
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import signal
import tempfile
import time
from pathlib import Path
from typing import Any, Mapping

from capstan.controller.runtime.daemon import Daemon
from capstan.controller.law.records import FaultBits
from capstan.tools.commands.run import EXIT_DEVICE_LOST, EXIT_FAULT
from capstan.controller.runtime.config import DaemonConfig
from capstan.models.common.config_tools import load_yaml
from capstan.models.common.errors import ConfigError, ControlFaultError, DeviceTimeoutError, DriverError, UsageError
from capstan.tools.hil.serve import (PLANT_START_TIMEOUT_S, RigProcess, ServedRig, load_plant, served_config,
                                     with_devices, write_config)
from capstan.tools.offline.shipped import config_path

HELP = "hardware-in-the-loop: simulated rig in its own process + the daemon unchanged"

log = logging.getLogger("capstan.hil")

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``capstan hil``."""
    parser.add_argument("--config", default=None,
                        help="HIL config YAML (default: the shipped hil.yaml, logs under ./runs/hil)")
    parser.add_argument("--plant", default=None, metavar="PLANT.yaml",
                        help="simulated rig from this plant file (hil.plant keys + sensors) instead of the config's")
    parser.add_argument("--serve", action="store_true",
                        help="run only the simulated rig of --plant; print its endpoints as one JSON line; "
                             "stop on SIGINT/SIGTERM")
    duration = parser.add_mutually_exclusive_group()
    duration.add_argument("--duration-s", type=float, default=None, metavar="S",
                          help="seconds of control (required unless --serve)")
    duration.add_argument("--duration", dest="duration_s", type=float, help=argparse.SUPPRESS)   # deprecated spelling
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")


def run(args: argparse.Namespace) -> int:
    """Run the HIL session; returns the exit code.

    :raises CapstanError: on configuration or start-up errors (exit code 2).
    """
    if args.serve:
        return serve(args)
    if args.duration_s is None or not args.duration_s > 0:
        raise UsageError(f"--duration-s must be given and > 0, got {args.duration_s}")
    path = config_path("hil.yaml") if args.config is None else Path(args.config)
    # relative log dirs: beside the config folder of a checkout, the working directory for
    # the shipped config (never inside the installed package)
    base_dir = Path.cwd() if args.config is None else path.resolve().parent.parent
    raw = load_yaml(path)
    DaemonConfig.from_mapping(raw, base_dir=base_dir, source=path)  # fail early
    channel = tempfile.mkdtemp(prefix="capstan-can-")
    rig_path = path
    if args.plant is not None:
        rig_path = write_config(served_config(load_plant(args.plant), raw.get("hil")),
                                Path(channel + "-rig.yaml"))
    rig = RigProcess(rig_path, channel)
    daemon: Daemon | None = None
    code = 0
    plant: dict[str, Any] = {}
    t_wall = time.monotonic()
    try:
        ports = rig.wait_ready(PLANT_START_TIMEOUT_S)
        cfg = DaemonConfig.from_mapping(with_devices(raw, ports), base_dir=base_dir, source=path)
        daemon = Daemon(cfg)
        try:
            daemon.run(duration_s=args.duration_s)
        except ControlFaultError as exc:
            log.error("stopped on a fault: %s", exc.reason)
            code = EXIT_DEVICE_LOST if exc.bits & FaultBits.DEVICE_LOST else EXIT_FAULT
            if rig.proc.poll() is not None:
                log.error("device loss: the simulated rig process is gone (exit code %s)", rig.proc.returncode)
                code = EXIT_DEVICE_LOST
        except DriverError:
            if rig.proc.poll() is not None:
                code = 4
            raise
    finally:
        plant = rig.stop()
        shutil.rmtree(channel, ignore_errors=True)
        if rig_path != path:
            rig_path.unlink(missing_ok=True)
    if "error" in plant:
        code = 4
    summary = summarize(daemon, plant, time.monotonic() - t_wall)
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"cycles {summary['cycles']}, missed {summary['missed']}, jitter p50/p99/p99.9/max "
              f"{summary['jitter_p50_us']:.0f}/{summary['jitter_p99_us']:.0f}/{summary['jitter_p999_us']:.0f}/"
              f"{summary['jitter_max_us']:.0f} us, faults {summary['faults']}, "
              f"dropped log records {summary['dropped_log_records']}, log {summary['log_path']}")
        c = summary["command"]
        if c:
            print(f"command: std {c['cmd_std_Nm']:.4f} Nm, change {c['cmd_change_rms_Nm']:.4f} Nm/cycle rms, "
                  f"{100 * c['cmd_hf_share']:.1f} % of its power above 20 Hz, {c['rate_limit_hits']} rate-limit hits; "
                  f"tau_in std {c['tau_in_std_Nm']:.4f} Nm")
    return code


def serve(args: argparse.Namespace) -> int:
    """``--serve``: the rig alone until SIGINT/SIGTERM; 4 if it stopped on its own.

    :raises ConfigError: without ``--plant`` or on an unreadable plant file.
    """
    if args.plant is None:
        raise ConfigError("--plant", "--serve needs the plant file to serve")
    stop = {"now": False}

    def _on_signal(signum: int, frame: Any) -> None:
        stop["now"] = True

    old = {sig: signal.signal(sig, _on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    served = ServedRig(load_plant(args.plant))
    try:
        print(json.dumps(served.start()), flush=True)
        while not stop["now"] and served.alive():
            time.sleep(0.05)
        died = not served.alive()
    finally:
        stats = served.close()
        for sig, handler in old.items():
            signal.signal(sig, handler)
    if died or "error" in stats:
        log.error("the simulated rig stopped on its own: %s", stats.get("error", "process ended"))
        return 4
    return 0


def summarize(daemon: Daemon | None, plant: Mapping[str, Any], wall_s: float) -> dict[str, Any]:
    """The one JSON object of ``capstan hil --json``."""
    s = daemon.summary if daemon is not None else None
    t = s.timing if s is not None else {}
    nan = float("nan")
    return {
        "cycles": s.cycles if s else 0,
        "missed": s.missed if s else 0,
        "overruns": s.overruns if s else 0,
        "jitter_p50_us": t.get("jitter_p50_us", nan),
        "jitter_p99_us": t.get("jitter_p99_us", nan),
        "jitter_p999_us": t.get("jitter_p999_us", nan),
        "jitter_max_us": t.get("jitter_max_us", nan),
        "latency_p999_us": t.get("latency_p999_us", nan),
        "compute_max_us": t.get("compute_max_us", nan),
        "gil_wait_p999_us": t.get("gil_wait_p999_us", nan),
        "gil_wait_max_us": t.get("gil_wait_max_us", nan),
        "faults": list(s.faults) if s else [],
        "fault_gap_s": s.fault_gap_s if s else 0.0,
        "dropped_log_records": s.dropped_log_records if s else 0,
        "command": dict(s.command) if s else {},
        "log_path": s.log_path if s else None,
        "cpu_s": dict(s.cpu_s) if s else {},
        "loop_wall_s": s.loop_wall_s if s else 0.0,
        "threads": list(s.threads) if s else [],
        "links": dict(s.links) if s else {},
        "plant": dict(plant),
        "wall_s": wall_s,
    }
