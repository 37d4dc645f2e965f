"""Latency figures that used to be asserted inside unit tests (a wall-clock bound in a threaded
test is a load test of the host, not of the code). The unit tests now check the rule and the
order of events; this script prints the distributions:

* drive heartbeat loss (tests/test_canopen_motor.py): the drive's heartbeat (10 ms) stops; time
  from its last heartbeat to ``HeartbeatLostError`` in the master (rule: after 3 periods, 30 ms);
* daemon heartbeat stop (tests/test_canopen_motor.py): the master stops cycling; time from its last
  heartbeat to the simulated drive's FAULT with zero torque (rule: consumer time 0x1016, 50 ms);
* IMU stream (tests/test_xsens_driver.py): frames per second the driver reads from the simulated
  MTi over a pty (device rate 400 Hz);
* log flush (tests/test_log_writer.py): time to compress and write one flush interval of 1 kHz
  records (the writer's loss bound is flush interval + this < 1 s).

Run from the repository root: ``.venv/bin/python tests/bench_latency.py [--repeats 10]``; prints
median / p90 / max per figure and the load average. Not collected by pytest (no ``test_`` prefix).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from cia402_helpers import Rig, make_motor, run_cycles  # noqa: E402
from capstan.controller.log.mcap_log import DEFAULT_FLUSH_INTERVAL_S, McapLog  # noqa: E402
from capstan.controller.log.writer import LIVE_ZSTD_LEVEL  # noqa: E402
from capstan.drivers.canopen.cia402 import State402  # noqa: E402
from capstan.drivers.serial.xsens import XsensConfig, XsensImu  # noqa: E402
from capstan.drivers.sim.serial_devices import SimXsens, open_pty_pair  # noqa: E402
from capstan.models.common.errors import HeartbeatLostError  # noqa: E402
from test_log_writer import DT, make_records  # noqa: E402
from test_xsens_driver import SimRunner, _collect  # noqa: E402


def _stats(name: str, xs: list[float], unit: str, scale: float) -> str:
    s = sorted(xs)
    p90 = s[min(len(s) - 1, int(round(0.9 * (len(s) - 1))))]
    return (f"{name:34s} n={len(s):3d}  median {scale * statistics.median(s):8.2f}  p90 {scale * p90:8.2f}  "
            f"max {scale * s[-1]:8.2f} {unit}")


def _pair(tmp: Path, **cfg: object):
    channel = str(tmp / f"can{time.monotonic_ns()}")
    rig = Rig(channel)
    motor, bus = make_motor(channel, **cfg)
    return rig, motor, bus


def heartbeat_loss_s(tmp: Path) -> float:
    rig, motor, bus = _pair(tmp, drive_heartbeat_period_s=0.01)
    try:
        motor.start()
        run_cycles(motor, 20)
        rig.servicing = False
        try:
            for _ in range(2000):
                run_cycles(motor, 1)
        except HeartbeatLostError:
            return time.monotonic() - motor._hb_last_s
        raise RuntimeError("heartbeat loss not detected in 2000 cycles")
    finally:
        motor.close(); bus.shutdown(); rig.close()


def daemon_heartbeat_stop_s(tmp: Path) -> float:
    rig, motor, bus = _pair(tmp, consumer_timeout_s=0.05)
    try:
        motor.start()
        run_cycles(motor, 30, torque_Nm=0.8)
        last = motor._hb_next_s - motor.config.heartbeat_period_s
        deadline = time.monotonic() + 5.0
        while rig.sim.state != State402.FAULT and time.monotonic() < deadline:
            time.sleep(0.0005)
        return time.monotonic() - last
    finally:
        motor.close(); bus.shutdown(); rig.close()


def imu_rate_hz() -> float:
    pty = open_pty_pair()
    try:
        sim = SimXsens(pty.master_fd)
        imu = XsensImu(XsensConfig.from_mapping({"port": pty.slave_path, "timeout_s": 0.3}))
        with SimRunner(sim):
            imu.start()
            good0 = imu.stats.good_frames
            t0 = time.monotonic()
            _collect(imu, 0.5)
            rate = (imu.stats.good_frames - good0) / (time.monotonic() - t0)
        imu.close()
        return rate
    finally:
        pty.close()


def flush_s(tmp: Path) -> float:
    r = make_records(int(1000 * DEFAULT_FLUSH_INTERVAL_S))
    log = McapLog(tmp / f"f{time.monotonic_ns()}", "p", DT, zstd_level=LIVE_ZSTD_LEVEL)
    log.write_records(r)
    c0 = time.perf_counter()
    log.flush()
    took = time.perf_counter() - c0
    log.close()
    return took


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=10)
    n = ap.parse_args(argv).repeats
    print(f"load average {os.getloadavg()[0]:.1f} / {os.getloadavg()[1]:.1f} on {os.cpu_count()} CPUs; {n} repeats")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        print(_stats("drive heartbeat loss (rule 30 ms)", [heartbeat_loss_s(tmp) for _ in range(n)], "ms", 1e3))
        print(_stats("daemon heartbeat stop (rule 50 ms)", [daemon_heartbeat_stop_s(tmp) for _ in range(n)], "ms", 1e3))
        print(_stats("IMU frames read (device 400 Hz)", [imu_rate_hz() for _ in range(n)], "Hz", 1.0))
        print(_stats(f"flush of {DEFAULT_FLUSH_INTERVAL_S} s of records", [flush_s(tmp) for _ in range(n)], "ms", 1e3))
    return 0


if __name__ == "__main__":
    sys.exit(main())
