"""Benchmark: cost of ``XsensImu.poll()`` and ``SerialLoadCells.poll()`` per call.

A child process plays the simulated MTi (400 Hz MTData2) and the load-cell amplifier
(1 kHz frames) on pty pairs; this process runs the real drivers in a 1 kHz loop on
absolute deadlines and times each ``poll()`` with ``perf_counter_ns``. Prints median,
p99 and max in µs, for calls that decoded a sample and for empty calls.

Also the parser alone: whole packets, packets split in two (look-ahead path) and a
forged maximal header before every 4th packet, with ratios in the same run.

Run:  .venv/bin/python tools/bench/serial_links.py [--duration 5]
"""

from __future__ import annotations

import argparse
import math
import multiprocessing as mp
import os
import time

import numpy as np


class _ByteSink:
    """A write-only port that keeps what the simulated device sends."""

    in_waiting = 0

    def __init__(self) -> None:
        self.data = bytearray()

    def write(self, b: bytes) -> int:
        self.data += b
        return len(b)


def _devices(imu_fd: int, lc_fd: int, duration_s: float) -> None:
    from capstan.drivers.sim.serial_devices import SimLoadCellAmp, SimXsens

    imu = SimXsens(imu_fd)
    amp = SimLoadCellAmp(lc_fd)
    t0 = time.monotonic()
    k = 0
    while True:
        now = time.monotonic()
        if now - t0 > duration_s:
            return
        imu.service()
        amp.service()
        while t0 + k * 1e-3 <= now:
            t = k * 1e-3
            amp.emit((150 + 40 * math.sin(t), 140.0, 140.0, 150 - 40 * math.sin(t)))
            if k % 5 in (0, 2):  # 2 packets per 5 ms = 400 Hz
                imu.emit(t, math.sin(t), math.cos(t))
            k += 1
        time.sleep(max(0.0, t0 + k * 1e-3 - time.monotonic()))


def _stats(ns: list[int]) -> str:
    if not ns:
        return "n=0"
    a = np.asarray(ns, dtype=float) / 1e3
    return f"n={a.size:6d} median={np.median(a):7.1f} us  p99={np.percentile(a, 99):7.1f} us  max={a.max():8.1f} us"


def _decode_only(n: int = 20000) -> None:
    """Pure decoding cost per frame, no I/O (feed one frame at a time)."""
    from capstan.drivers.serial.loadcell_protocol import LoadCellParser, build_frame
    from capstan.drivers.sim.serial_devices import SimXsens
    from capstan.drivers.serial.xsens import XsensConfig, joint_from_mtdata2
    from capstan.drivers.serial.xsens_protocol import XbusParser, parse_mtdata2

    sink = _ByteSink()
    sim = SimXsens(sink)
    sim.emit(0.1, 0.2, 0.3)
    pkt = bytes(sink.data)
    cfg = XsensConfig(port="-")
    xp = XbusParser()
    a = time.perf_counter_ns()
    for _ in range(n):
        for _, d in xp.feed(pkt):
            joint_from_mtdata2(parse_mtdata2(d), cfg)
    b = time.perf_counter_ns()
    frame = build_frame((0.6, 0.56, 0.56, 0.6))
    lp = LoadCellParser()
    lp.feed(frame)
    c = time.perf_counter_ns()
    for _ in range(n):
        lp.feed(frame)
    d_ = time.perf_counter_ns()
    print(f"  decode only: Xsens packet ({len(pkt)} B) {(b - a) / n / 1e3:.1f} us, "
          f"load-cell frame {(d_ - c) / n / 1e3:.1f} us")


def _parser_paths(n: int = 4000, repeats: int = 7) -> None:
    """Xbus parser cost per packet (bounded as the driver bounds it) on three streams:
    whole packets; each packet in two halves (a pending candidate at every feed, so the
    look-ahead runs); a forged ``FA FF 36 FF 07 FF`` before every 4th packet. Median of
    ``repeats`` runs, and the ratio to the whole-packet stream measured in the same run."""
    import statistics

    from capstan.drivers.serial.xsens import XsensConfig, output_configuration
    from capstan.drivers.serial.xsens_protocol import Mid, XbusParser, mtdata2_max_len
    from capstan.drivers.sim.serial_devices import SimXsens

    sink = _ByteSink()
    sim = SimXsens(sink)
    pkts = []
    for k in range(n):
        sim.emit(k / 400, math.sin(k / 400), 0.1)
        pkts.append(bytes(sink.data))
        sink.data.clear()
    bound = mtdata2_max_len(output_configuration(XsensConfig(port="-")))
    forged = bytes.fromhex("FA FF 36 FF 07 FF")
    streams = {
        "whole": pkts,
        "halves": [c for p in pkts for c in (p[:len(p) // 2], p[len(p) // 2:])],
        "forged/4": [(forged if k % 4 == 0 else b"") + p for k, p in enumerate(pkts)],
    }
    med: dict[str, float] = {}
    for name, chunks in streams.items():
        runs = []
        for _ in range(repeats):
            xp = XbusParser(max_data_len=254, limits={Mid.MT_DATA2: bound})
            a = time.perf_counter_ns()
            got = 0
            for c in chunks:
                got += len(xp.feed(c))
            runs.append((time.perf_counter_ns() - a) / n / 1e3)
            assert got == n, (name, got)
        med[name] = statistics.median(runs)
    print("  parser per packet (median of %d x %d packets): " % (repeats, n)
          + ", ".join(f"{k} {v:.2f} us ({v / med['whole']:.2f}x)" for k, v in med.items()))


def main() -> int:
    """Run the benchmark and print the figures."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=5.0, help="measured seconds")
    args = ap.parse_args()

    from capstan.drivers.serial.loadcell import LoadCellConfig, SerialLoadCells
    from capstan.drivers.sim.serial_devices import open_pty_pair
    from capstan.drivers.serial.xsens import XsensConfig, XsensImu

    imu_pty, lc_pty = open_pty_pair(), open_pty_pair()
    child = mp.get_context("fork").Process(
        target=_devices, args=(imu_pty.master_fd, lc_pty.master_fd, args.duration + 3.0), daemon=True)
    child.start()
    imu = XsensImu(XsensConfig(port=imu_pty.slave_path))
    cells = SerialLoadCells(LoadCellConfig(port=lc_pty.slave_path))
    try:
        imu.start()
        cells.start()
        timings: dict[str, list[int]] = {"imu sample": [], "imu empty": [], "lc sample": [], "lc empty": []}
        t0 = time.monotonic()
        k = 0
        end = t0 + args.duration
        while time.monotonic() < end:
            a = time.perf_counter_ns()
            s = imu.poll()
            b = time.perf_counter_ns()
            timings["imu sample" if s is not None else "imu empty"].append(b - a)
            a = time.perf_counter_ns()
            c = cells.poll()
            b = time.perf_counter_ns()
            timings["lc sample" if c is not None else "lc empty"].append(b - a)
            k += 1
            time.sleep(max(0.0, t0 + k * 1e-3 - time.monotonic()))
        print(f"bench_serial: {k} cycles of 1 ms, pid {os.getpid()}")
        for name, ns in timings.items():
            print(f"  poll {name:11s} {_stats(ns)}")
        _decode_only()
        _parser_paths()
        print(f"  imu  {imu.stats}")
        print(f"  load {cells.stats}")
    finally:
        imu.close()
        cells.close()
        child.terminate()
        child.join(2.0)
        imu_pty.close()
        lc_pty.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
