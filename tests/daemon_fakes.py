"""In-process fake devices and a fake controller for the daemon tests (no bus, no plant).

The fake controller follows the controller contract (``record`` of RECORD_DTYPE,
``step() -> tau``, ``warmup()``) and latches the external fault bits, stale sensors
and non-finite inputs the way the safety stage does, so the daemon's reaction is what
is under test.
"""

from __future__ import annotations

import math
import socket
import time
from pathlib import Path
from typing import Any

import numpy as np

from capstan.controller.runtime.config import DaemonConfig
from capstan.controller.law.records import RECORD_DTYPE, FaultBits
from capstan.drivers.interfaces import DeviceSet, ImuSample, LinkStats, LoadCellSample, MotorReading
from capstan.models.common.errors import DriveFaultError, HeartbeatLostError


class FakeController:
    def __init__(self, tau_Nm: float = 0.5, stale_s: float = 0.05) -> None:
        self.record = np.zeros(1, RECORD_DTYPE)
        self.tau_Nm = tau_Nm
        self.stale_s = stale_s
        self.warmed = False
        self.steps = 0

    def warmup(self) -> None:
        self.warmed = True

    def step(self) -> float:
        r = self.record[0]
        self.steps += 1
        bits = int(r["fault_bits"]) | int(r["ext_fault_bits"])
        t = r["t_s"]
        if t - r["imu_t_s"] > self.stale_s:
            bits |= FaultBits.STALE_IMU
        if t - r["lc_t_s"] > self.stale_s:
            bits |= FaultBits.STALE_LOADCELL
        if not all(math.isfinite(r[k]) for k in ("T_up_in_N", "q_out_rad", "dq_out_rad_s", "q_m_rad")):
            bits |= FaultBits.NONFINITE_INPUT
        tau = 0.0 if bits else self.tau_Nm
        r["fault_bits"] = bits
        r["tau_m_cmd_Nm"] = tau
        return tau


class FakeMotor:
    def __init__(self, journal: list[str], fault_at: int | None = None, hb_lost_at: int | None = None,
                 slow_from: int | None = None, slow_s: float = 0.003) -> None:
        self.journal = journal
        self.fault_at, self.hb_lost_at = fault_at, hb_lost_at
        self.slow_from, self.slow_s = slow_from, slow_s
        self.polls = 0
        self.staged = math.nan
        self.sent: list[float] = []
        self.disabled = 0

    def start(self) -> None:
        self.journal.append("motor enabled")

    def poll(self) -> MotorReading | None:
        self.polls += 1
        if self.fault_at is not None and self.polls >= self.fault_at:
            raise DriveFaultError("EMCY 0x2310 continuous over current")
        if self.hb_lost_at is not None and self.polls >= self.hb_lost_at:
            raise HeartbeatLostError("no heartbeat from node 1 for 0.3 s")
        return MotorReading(t_s=time.monotonic(), position_rad=0.1, velocity_rad_s=0.0, torque_Nm=self.staged)

    def write_torque(self, torque_Nm: float) -> None:
        self.staged = torque_Nm

    def send_cycle(self) -> None:
        self.sent.append(self.staged)
        if self.slow_from is not None and len(self.sent) >= self.slow_from:
            time.sleep(self.slow_s)

    def disable(self) -> None:
        self.disabled += 1
        self.journal.append(f"motor disabled after {len(self.sent)} commands")

    def quick_stop(self) -> None:
        pass

    def fault_reset(self) -> None:
        pass

    def close(self) -> None:
        self.journal.append("motor closed")


class FakeImu:
    def __init__(self, every: int = 2, stop_after: int | None = None, q_of_poll: Any = None) -> None:
        self.stats = LinkStats()
        self.every, self.stop_after = every, stop_after
        self.q_of_poll = q_of_poll or (lambda n: 0.2)
        self.polls = 0

    def start(self) -> None:
        pass

    def poll(self) -> ImuSample | None:
        self.polls += 1
        if self.stop_after is not None and self.polls > self.stop_after:
            return None
        if self.polls % self.every:
            return None
        return ImuSample(t_s=time.monotonic(), q_out_rad=self.q_of_poll(self.polls), dq_out_rad_s=0.0)

    def close(self) -> None:
        pass


class FakeLoadCells:
    def __init__(self, nan_at: int | None = None) -> None:
        self.stats = LinkStats()
        self.nan_at = nan_at
        self.polls = 0

    def start(self) -> None:
        pass

    def poll(self) -> LoadCellSample | None:
        self.polls += 1
        T = math.nan if self.nan_at is not None and self.polls >= self.nan_at else 150.0
        return LoadCellSample(t_s=time.monotonic(), tensions_N=(T, 150.0, 150.0, 150.0))

    def close(self) -> None:
        pass


def devices(journal: list[str], motor: FakeMotor | None = None, imu: FakeImu | None = None,
            cells: FakeLoadCells | None = None) -> DeviceSet:
    return DeviceSet(motor or FakeMotor(journal), imu or FakeImu(), cells or FakeLoadCells())


def config(**loop: Any) -> DaemonConfig:
    base = {"period_s": 1e-3, "ramp_down_s": 0.05, "startup_timeout_s": 0.3, "stats_interval_s": 0.1,
            "overrun_streak_fault": 5, "arm_on_time_cycles": 20}
    base.update(loop)
    return DaemonConfig.from_mapping({
        "controller": {}, "motor": {"backend": "fake"}, "imu": {"backend": "fake"},
        "load_cells": {"backend": "fake"}, "realtime": {"mode": "off"}, "loop": base,
        "logging": {"fault_history_cycles": 50},
    })


class NotifyListener:
    """A real NOTIFY_SOCKET datagram server collecting the messages."""

    def __init__(self, tmp: Path) -> None:
        self.path = str(tmp / "notify.sock")
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(self.path)
        self.sock.setblocking(False)

    def messages(self) -> list[str]:
        out = []
        while True:
            try:
                out.append(self.sock.recv(4096).decode())
            except BlockingIOError:
                return out
