"""``capstan hil [--config config/hil.yaml] --duration-s S [--json]``: hardware-in-the-loop run.

Starts the simulated rig in its own process (:mod:`capstan.tools.hil.plant`: plant in real
time, simulated drive on a fresh ``capstan_unix`` bus, IMU and load cells on pty
pairs), points the config's ``auto`` channel/ports at it and runs the daemon unchanged
for ``S`` seconds of control, then ramps down and prints a summary — with ``--json``
one object: cycles, missed, period jitter p50/p99/p99.9/max [µs], faults, dropped log
records, log path (plus the plant's and the processes' CPU figures; under ``plant``
the simulated rig's statistics, with ``hand`` the interaction torque of ``hil.hand`` and
``effects`` the effects injected into the plant).

Exit codes as ``capstan run`` (0 ok, 2 start-up error, 3 control fault, 4 device loss);
4 also if the simulated rig failed (e.g. cable slack) or its process died.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Mapping

from capstan.controller.runtime.daemon import Daemon
from capstan.controller.law.records import FaultBits
from capstan.tools.commands.run import EXIT_DEVICE_LOST, EXIT_FAULT
from capstan.controller.runtime.config import DaemonConfig
from capstan.models.common.config_tools import load_yaml
from capstan.models.common.errors import ControlFaultError, DeviceTimeoutError, DriverError, UsageError
from capstan.tools.offline.shipped import config_path

HELP = "hardware-in-the-loop: simulated rig in its own process + the daemon unchanged"

log = logging.getLogger("capstan.hil")

#: time for the rig process to compile its plant and open its devices [s]
PLANT_START_TIMEOUT_S = 120.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``capstan hil``."""
    parser.add_argument("--config", default=None,
                        help="HIL config YAML (default: the shipped hil.yaml, logs under ./runs/hil)")
    duration = parser.add_mutually_exclusive_group(required=True)
    duration.add_argument("--duration-s", type=float, metavar="S", help="seconds of control")
    duration.add_argument("--duration", dest="duration_s", type=float, help=argparse.SUPPRESS)   # deprecated spelling
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")


def with_devices(cfg: Mapping[str, Any], ports: Mapping[str, Any]) -> dict[str, Any]:
    """Copy of the config with ``auto`` bus channel and serial ports replaced by the rig's."""
    out = {k: (dict(v) if isinstance(v, Mapping) else v) for k, v in cfg.items()}
    if out.get("motor", {}).get("channel") == "auto":
        out["motor"]["channel"] = ports["channel"]
    if out.get("imu", {}).get("port") == "auto":
        out["imu"]["port"] = ports["imu_port"]
    if out.get("load_cells", {}).get("port") == "auto":
        out["load_cells"]["port"] = ports["load_cells_port"]
    return out


class RigProcess:
    """The simulated rig child process and its stdout protocol."""

    def __init__(self, config_path: Path, channel: str) -> None:
        cmd = [sys.executable, "-m", "capstan.tools.hil.plant", "--config", str(config_path), "--channel", channel,
               "--parent-pid", str(os.getpid())]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)

    def wait_ready(self, timeout_s: float) -> dict[str, Any]:
        """The handshake line of the rig.

        :raises DeviceTimeoutError: if the rig does not come up in time or exits.
        """
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout_s)
        line = self.proc.stdout.readline() if ready else ""
        if not line:
            exited = ready                          # end of stream: the rig process ended
            self.stop()
            if exited:
                raise DeviceTimeoutError(f"simulated rig exited during start-up with code "
                                         f"{self.proc.returncode} (its error is logged above)")
            raise DeviceTimeoutError(f"simulated rig did not start within {timeout_s} s")
        return json.loads(line)

    def stop(self, timeout_s: float = 10.0) -> dict[str, Any]:
        """SIGTERM, wait, and return the rig's statistics line ({} if none)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            out, _ = self.proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            out, _ = self.proc.communicate()
        lines = [ln for ln in (out or "").splitlines() if ln.startswith("{")]
        return json.loads(lines[-1]) if lines else {}


def run(args: argparse.Namespace) -> int:
    """Run the HIL session; returns the exit code.

    :raises CapstanError: on configuration or start-up errors (exit code 2).
    """
    if not args.duration_s > 0:
        raise UsageError(f"--duration-s must be > 0, got {args.duration_s}")
    path = config_path("hil.yaml") if args.config is None else Path(args.config)
    # relative log dirs: beside the config folder of a checkout, the working directory for
    # the shipped config (never inside the installed package)
    base_dir = Path.cwd() if args.config is None else path.resolve().parent.parent
    raw = load_yaml(path)
    DaemonConfig.from_mapping(raw, base_dir=base_dir, source=path)  # fail early
    channel = tempfile.mkdtemp(prefix="capstan-can-")
    rig = RigProcess(path, channel)
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
