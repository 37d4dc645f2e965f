"""Test harness: a simulated drive serviced by a rig thread, a motor driver and a bus spy.

All three talk over one ``capstan_unix`` channel (each with its own bus instance, as
separate processes would), so the driver code runs unchanged against the simulated
drive.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import can

from capstan.drivers.can_unix import UnixSocketBus
from capstan.drivers.canopen.motor import CanopenMotor
from capstan.drivers.canopen.config import DATA_DIR, MotorConfig
from capstan.drivers.sim.drive import SimDrive

ROOT = Path(__file__).resolve().parents[1]
CAPSTAN_EDS = str(DATA_DIR / "capstan_drive.eds")
VENDOR_EDS = str(ROOT / "tests" / "data" / "nanotec_C5-E-2-09.eds")
NODE_ID = 3


class Spy:
    """Records every frame on the channel (its own bus + reader thread)."""

    def __init__(self, channel: str) -> None:
        self.bus = UnixSocketBus(channel)
        self.frames: list[tuple[float, int, bytes]] = []
        self._stop = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop:
            msg = self.bus.recv(0.02)
            if msg is not None:
                self.frames.append((time.monotonic(), msg.arbitration_id, bytes(msg.data)))

    def ids(self, can_id: int) -> list[bytes]:
        return [d for _, i, d in self.frames if i == can_id]

    def close(self) -> None:
        self._stop = True
        self._thread.join(2)
        self.bus.shutdown()


class Rig:
    """A simulated drive on its own bus, serviced every ms by a rig thread.

    The plant is a constant-feedback stub: position/velocity given, torque = command.
    """

    def __init__(self, channel: str, eds: str = CAPSTAN_EDS, rated_torque_Nm: float = 2.0,
                 **sim_kwargs: object) -> None:
        self.bus = UnixSocketBus(channel)
        self.sim = SimDrive(self.bus, NODE_ID, eds, rated_torque_Nm=rated_torque_Nm, **sim_kwargs)
        self.position_rad = 1.0
        self.velocity_rad_s = -2.0
        self.servicing = True   # False: the drive stops producing its heartbeat
        self.error: BaseException | None = None
        self._stop = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            while not self._stop:
                self.sim.set_feedback(self.position_rad, self.velocity_rad_s, self.sim.torque_command_Nm)
                if self.servicing:
                    self.sim.service(time.monotonic())
                time.sleep(0.0005)
        except BaseException as exc:  # surfaced by close()
            self.error = exc

    def close(self) -> None:
        self._stop = True
        self._thread.join(2)
        self.sim.close()
        self.bus.shutdown()
        if self.error is not None:
            raise self.error


def make_motor(channel: str, eds: str = CAPSTAN_EDS, **cfg: object) -> tuple[CanopenMotor, can.BusABC]:
    options = {"node_id": NODE_ID, "eds": eds, "interface": "capstan_unix", "channel": channel,
               # lenient where heartbeat timing is not what a test is about (shared 2-core machine)
               "drive_heartbeat_period_s": 0.05, "heartbeat_period_s": 0.01, "consumer_timeout_s": 0.2}
    options.update(cfg)
    bus = UnixSocketBus(channel)
    return CanopenMotor(MotorConfig.from_mapping(options), bus=bus), bus


def run_cycles(motor: CanopenMotor, n: int, torque_Nm: float = 0.0, period_s: float = 0.001) -> None:
    """n control cycles: write, send, wait, poll (faults propagate)."""
    for _ in range(n):
        motor.write_torque(torque_Nm)
        motor.send_cycle()
        time.sleep(period_s)
        motor.poll()
