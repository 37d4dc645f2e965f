"""A static rig around the independent CiA 402 peer, for ``capstan run`` end to end.

The peer drive (tests/cia402_peer) on a ``capstan_unix`` channel, and the simulated IMU
and load-cell amplifier on pty pairs fed from a thread with a fixed link angle and fixed
tensions; :func:`run_config` writes a daemon config pointing at them.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import yaml

from cia402_peer import PeerDrive
from capstan.drivers.can_unix import UnixSocketBus
from capstan.drivers.sim.serial_devices import SimLoadCellAmp, SimXsens, open_pty_pair

REPO = Path(__file__).resolve().parent.parent
VENDOR_EDS = str(REPO / "tests" / "data" / "nanotec_C5-E-2-09.eds")
NODE_ID = 1
RATED_NM = 20.0


class PeerRig:
    """Peer drive + IMU + load cells, serviced by one thread; :meth:`close` stops everything."""

    def __init__(self, channel: str, q_out_rad: float = 0.3, tension_N: float = 150.0,
                 **peer_kwargs: Any) -> None:
        self.peer = PeerDrive(UnixSocketBus(channel), NODE_ID, VENDOR_EDS, **peer_kwargs).start()
        self.imu_pty, self.lc_pty = open_pty_pair(), open_pty_pair()
        self.imu = SimXsens.from_config(self.imu_pty.master_fd, {"port": self.imu_pty.slave_path,
                                                                  "output_rate_hz": 400, "joint_axis": "z"})
        self.cells = SimLoadCellAmp.from_config(self.lc_pty.master_fd, {"port": self.lc_pty.slave_path})
        self.q_out_rad, self.tension_N = q_out_rad, tension_N
        self.error: BaseException | None = None
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="peer-rig", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            t0 = time.monotonic()
            next_imu = next_cells = t0
            while not self._stop:
                now = time.monotonic()
                self.imu.service()
                self.cells.service()
                if now >= next_imu:
                    self.imu.emit(now - t0, self.q_out_rad, 0.0)
                    next_imu = max(next_imu + 0.0025, now - 0.0025)
                if now >= next_cells:
                    self.cells.emit((self.tension_N,) * 4)
                    next_cells = max(next_cells + 0.001, now - 0.001)
                time.sleep(max(0.0, min(next_imu, next_cells) - time.monotonic()))
        except BaseException as exc:  # surfaced by close()
            self.error = exc

    def close(self) -> None:
        self._stop = True
        self._thread.join(2)
        self.peer.close()
        self.peer.bus.shutdown()
        self.imu_pty.close()
        self.lc_pty.close()
        if self.error is not None:
            raise self.error

    def run_config(self, path: Path, channel: str, log_dir: Path) -> Path:
        """A copy of config/hil.yaml pointing at this rig (vendor EDS, rated torque configured)."""
        cfg = yaml.safe_load((REPO / "config" / "hil.yaml").read_text())
        cfg.pop("hil", None)
        cfg["motor"].update({"channel": channel, "eds": VENDOR_EDS, "node_id": NODE_ID,
                             "rated_torque_Nm": RATED_NM})
        cfg["imu"]["port"] = self.imu_pty.slave_path
        cfg["load_cells"]["port"] = self.lc_pty.slave_path
        cfg["logging"]["dir"] = str(log_dir)
        cfg["realtime"]["lock_memory"] = False
        # the peer drive and the sensor streams are threads of the test process, which a loaded
        # host holds off the CPU for tens of ms: staleness limits at the top of their plausible
        # range, so these runs test the drive's life cycle rather than the host's scheduling
        cfg["controller"]["safety"].update({"imu_timeout_s": 0.1, "loadcell_timeout_s": 0.1, "motor_timeout_s": 0.1})
        path.write_text(yaml.safe_dump(cfg))
        return path
