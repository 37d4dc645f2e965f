"""Figures for the CANopen bring-up against the independent peer drive (tests/cia402_peer).

* start-up against drives booting 0.2 / 0.6 / 3 s after power-on: when ``start()`` returned,
  counted from the drive's power-on (the boot itself is part of it);
* SIGKILL of a master process commanding 0.5 Nm: time until the drive's torque is zero
  (consumer time 0x1016 = 100 ms, 5 kills; each followed by a start-up that must reset 0x8130);
* the disable of a drive that is gone: time until it gives up (drive heartbeat 50 ms, lost
  after 3 periods = 150 ms; 5 runs).

Run from the repository root: ``python tests/bench_cia402_peer.py``; prints one JSON object.
"""

from __future__ import annotations

import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from cia402_helpers import NODE_ID, VENDOR_EDS, make_motor, run_cycles  # noqa: E402
from cia402_peer import PeerDrive  # noqa: E402
from capstan.drivers.can_unix import UnixSocketBus  # noqa: E402
from capstan.models.common.errors import DeviceLostError  # noqa: E402


def _peer(**kwargs: object) -> tuple[str, PeerDrive]:
    channel = tempfile.mkdtemp(prefix="capstan-peer-") + "/can0"
    return channel, PeerDrive(UnixSocketBus(channel), NODE_ID, VENDOR_EDS, **kwargs).start()


def _done(peer: PeerDrive, motor: object, bus: object) -> None:
    motor.close()
    bus.shutdown()
    peer.close()
    peer.bus.shutdown()


def main() -> None:
    out: dict[str, object] = {}
    for boot_s in (0.2, 0.6, 3.0):
        t0 = time.monotonic()
        channel, peer = _peer(boot_delay_s=boot_s)
        motor, bus = make_motor(channel, eds=VENDOR_EDS, rated_torque_Nm=2.0)
        motor.start()
        out[f"enabled_after_power_on_s[boot {boot_s} s]"] = round(time.monotonic() - t0, 3)
        _done(peer, motor, bus)
    stops = []
    for _ in range(5):
        channel, peer = _peer()
        proc = subprocess.Popen([sys.executable, str(HERE / "canopen_master_proc.py"), channel, VENDOR_EDS, "0.5",
                                 "consumer_timeout_s=0.1"], stdout=subprocess.PIPE, text=True)
        assert proc.stdout is not None and proc.stdout.readline().strip() == "enabled"
        while peer.applied_torque_permille != 250:
            time.sleep(0.001)
        time.sleep(0.2)
        os.kill(proc.pid, signal.SIGKILL)
        t_kill = time.monotonic()
        while peer.applied_torque_permille != 0:
            time.sleep(0.0005)
        stops.append(time.monotonic() - t_kill)
        proc.wait()
        motor, bus = make_motor(channel, eds=VENDOR_EDS, rated_torque_Nm=2.0)
        motor.start()
        assert motor.recovered_fault == 0x8130
        _done(peer, motor, bus)
    out["sigkill_to_zero_torque_ms"] = [round(s * 1e3, 1) for s in stops]
    out["sigkill_to_zero_torque_median_ms"] = round(statistics.median(stops) * 1e3, 1)
    out["consumer_timeout_ms"] = 100
    gone = []
    for _ in range(5):
        channel, peer = _peer()
        motor, bus = make_motor(channel, eds=VENDOR_EDS, rated_torque_Nm=2.0)
        motor.start()
        run_cycles(motor, 20)
        peer.close()
        t0 = time.monotonic()
        try:
            motor.disable()
        except DeviceLostError:
            pass
        gone.append(time.monotonic() - t0)
        motor.close()
        bus.shutdown()
        peer.bus.shutdown()
    out["gone_drive_disable_gives_up_ms"] = [round(s * 1e3, 1) for s in gone]
    out["drive_heartbeat_timeout_ms"] = 150
    print(json.dumps(out))


if __name__ == "__main__":
    main()
