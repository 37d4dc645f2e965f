"""The simulated rig served from a plant file alone: ``capstan hil --serve --plant PLANT.yaml``.

A plant file (``PLANT.yaml``) holds the ``hil.plant`` mapping of
:meth:`capstan.models.plant.rig.SimulatedRig.from_mapping` (transmission, routing,
pretension, output, input, noise, seed, effects and the devices' ``sensors`` section) at
its top level, and optionally ``faults`` — device faults of the served rig
(``hil.faults`` of :class:`capstan.tools.hil.plant.HilSettings`, e.g.
``load_cells_silent_after_s``). :func:`served_config` wraps it into the configuration the rig process
(:mod:`capstan.tools.hil.plant`) reads: the ``hil`` section around the plant and the device
sections that say what the simulated hardware *is* (a CiA 402 drive at node 1 with the
shipped EDS, an MTi, a four-channel amplifier) — never what a client was told about it.
A client (the daemon, ``capstan rig bringup``) finds the devices from the one JSON line
of endpoints only.
"""

from __future__ import annotations

import json
import os
import select
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, Mapping

import yaml

from capstan.models.common.config_tools import load_yaml
from capstan.models.common.errors import ConfigError, DeviceTimeoutError

#: time for the rig process to compile its plant and open its devices [s]: over two minutes
#: on a loaded 2-core machine with a cold Numba cache (load average 24, 2026-11-28)
PLANT_START_TIMEOUT_S = 300.0

#: the simulated hardware's own settings (the drive, the MTi, the amplifier as delivered)
SERVED_DEVICES: dict[str, dict[str, Any]] = {
    "motor": {"backend": "canopen", "interface": "capstan_unix", "channel": "auto", "node_id": 1,
              "eds": "capstan_drive.eds", "mode": "cst"},
    "imu": {"backend": "xsens", "port": "auto", "output_rate_hz": 400, "joint_axis": "z"},
    "load_cells": {"backend": "serial", "port": "auto"},
}

#: the served rig's process settings: no external torque, no hand (the client moves the link)
SERVED_HIL: dict[str, Any] = {"period_s": 0.001, "drive": {"rated_torque_Nm": 20.0},
                              "realtime": {"mode": "warn", "priority": 70}}


def load_plant(path: str | Path) -> dict[str, Any]:
    """The plant mapping of a plant file.

    :raises ConfigError: if the file is not a mapping (the plant's own keys are checked by
        the rig process, naming ``hil.plant.<key>``).
    """
    raw = load_yaml(Path(path))
    if not isinstance(raw, Mapping) or not raw:
        raise ConfigError("plant", f"{path}: must be a mapping of the hil.plant keys (transmission, routing, ...)")
    return dict(raw)


def served_config(plant: Mapping[str, Any], hil: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The rig process's configuration for ``plant``.

    :param hil: ``hil`` settings besides the plant (tau_ext, hand, realtime ...); default
        :data:`SERVED_HIL`.
    """
    h = {k: v for k, v in (SERVED_HIL if hil is None else hil).items() if k != "plant"}
    p = {k: v for k, v in plant.items() if k != "faults"}
    if "faults" in plant:
        h["faults"] = plant["faults"]
    return {**{k: dict(v) for k, v in SERVED_DEVICES.items()}, "hil": {**h, "plant": p}}


def with_plant(cfg: Mapping[str, Any], plant: Mapping[str, Any]) -> dict[str, Any]:
    """A daemon config whose ``hil.plant`` is ``plant`` (the rest of ``hil`` kept)."""
    out = dict(cfg)
    out["hil"] = {**dict(cfg.get("hil") or {}), "plant": dict(plant)}
    return out


def write_config(cfg: Mapping[str, Any], path: Path) -> Path:
    """Write a served configuration for the rig process."""
    path.write_text(yaml.safe_dump(dict(cfg), sort_keys=False))
    return path


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


class ServedRig:
    """The simulated rig of a plant file in its own process, on a fresh bus directory.

    :param plant: the plant mapping (``hil.plant`` keys plus ``sensors``).
    :param hil: ``hil`` settings besides the plant (default: no external torque, no hand).
    """

    def __init__(self, plant: Mapping[str, Any], hil: Mapping[str, Any] | None = None) -> None:
        self.channel = tempfile.mkdtemp(prefix="capstan-can-")
        self.config = write_config(served_config(plant, hil), Path(self.channel + "-rig.yaml"))
        self.rig = RigProcess(self.config, self.channel)
        self.ports: dict[str, Any] = {}

    def start(self, timeout_s: float = PLANT_START_TIMEOUT_S) -> dict[str, Any]:
        """Wait for the rig's endpoints.

        :raises DeviceTimeoutError: if it does not come up.
        """
        try:
            self.ports = self.rig.wait_ready(timeout_s)
        except DeviceTimeoutError:
            self.close()
            raise
        return self.ports

    def alive(self) -> bool:
        """True while the rig process runs."""
        return self.rig.proc.poll() is None

    def close(self) -> dict[str, Any]:
        """Stop the rig; its statistics line ({} if none)."""
        try:
            return self.rig.stop()
        finally:
            shutil.rmtree(self.channel, ignore_errors=True)
            self.config.unlink(missing_ok=True)
