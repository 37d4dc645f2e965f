"""Benchmark of the logging path (run on demand, prints figures; not a test).

    .venv/bin/python -m tools.bench_logging [--seconds 60] [--rate-hz 1000]

1. live run: a 1 kHz paced producer pushes realistic cycle records (the real
   controller stepping on noisy load-cell / IMU / motor signals) into a
   :class:`controller.log_writer.LogSession`; prints µs per push (median, p99, max),
   dropped records, bytes per record and MB per hour (extrapolated from the run);
2. writer throughput: a pre-filled ring drained by the writer loop in-process
   (records/s it sustains, i.e. its margin over 1 kHz);
3. replay speed on the log of the live run (read + step, x real time).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from controller.config import ControllerConfig
from controller.core import Controller
from controller.daemon_log import STATS_DTYPE
from controller.log_reader import read_log
from controller.log_ring import LogRing
from controller.log_writer import LogSession, run_writer
from controller.records import MEASUREMENT_FIELDS, RECORD_DTYPE, STEP_OUTPUT_FIELDS

#: limits raised so the open-loop synthetic run never saturates or faults: the command
#: stays a noisy float (the worst case for compression)
CONFIG = {"controller": {"feedback": {"kp": 4.0},
                         "safety": {"tau_max_Nm": 1000.0, "tau_fault_Nm": 2000.0,
                                    "dtau_max_Nm_s": 1e6, "dtau_fault_Nm_s": 1e7}}}


def realistic_records(n: int, seed: int = 7) -> np.ndarray:
    """Cycle records of a live-like run: 0.5 Hz + 3.1 Hz torque sines, load cells with
    0.2 N noise, IMU at 400 Hz held between samples (float32 resolution), motor feedback
    with noise, jittered loop time and timing fields, the real controller stepping."""
    rng = np.random.default_rng(seed)
    ctl = Controller(ControllerConfig.from_mapping(CONFIG["controller"]))
    ctl.warmup()
    out = np.zeros(n, RECORD_DTYPE)
    rec = ctl.record[0]
    t, q, dq, t_imu = 10.0, 0.0, 0.0, 10.0
    for k in range(n):
        t += 1e-3 + rng.normal(0, 3e-6)
        ph = 2 * np.pi * 0.5 * k * 1e-3
        tau = 3.0 * np.sin(ph) + 0.3 * np.sin(6.2 * ph)
        rec["cycle"], rec["t_s"] = k, t
        rec["T_up_in_N"] = 150 + tau / 0.08 + rng.normal(0, 0.2)
        rec["T_lo_in_N"] = 150 - tau / 0.08 + rng.normal(0, 0.2)
        rec["T_up_out_N"] = 146 + 0.9 * tau / 0.08 + rng.normal(0, 0.2)
        rec["T_lo_out_N"] = 146 - 0.9 * tau / 0.08 + rng.normal(0, 0.2)
        rec["lc_t_s"] = t - 1.5e-4 - abs(rng.normal(0, 5e-5))
        if k % 5 in (0, 2):
            q = float(np.float32(0.4 * np.sin(ph - 0.3) + rng.normal(0, 1e-4)))
            dq = float(np.float32(0.4 * np.pi * np.cos(ph - 0.3) + rng.normal(0, 2e-3)))
            t_imu = t - 3e-4 - abs(rng.normal(0, 5e-5))
            rec["imu_new"] = 1
        else:
            rec["imu_new"] = 0
        rec["q_out_rad"], rec["dq_out_rad_s"], rec["imu_t_s"] = q, dq, t_imu
        rec["q_m_rad"] = 0.41 * np.sin(ph - 0.25) + rng.normal(0, 1e-5)
        rec["dq_m_rad_s"] = 0.41 * np.pi * np.cos(ph - 0.25) + rng.normal(0, 1e-3)
        rec["tau_m_meas_Nm"] = tau + rng.normal(0, 0.05)
        # reference the loop is tracking: the measured torque follows it (closed loop)
        rec["tau_out_ref_Nm"] = tau - 3.78 * np.sin(q)
        rec["motor_t_s"] = t - 1e-4 - abs(rng.normal(0, 3e-5))
        ctl.step()
        rec["period_s"] = 1e-3 + rng.normal(0, 3e-6)
        rec["compute_s"] = 2e-5 + abs(rng.normal(0, 3e-6))
        rec["late"] = 0
        out[k] = rec
    return out


def live_run(records: np.ndarray, rate_hz: float, out_dir: Path, flush_interval_s: float,
             compression: str, float32_fields: tuple[str, ...] = ()) -> dict:
    """Push ``records`` at ``rate_hz`` into a LogSession; returns the figures."""
    s = LogSession(RECORD_DTYPE, out_dir, yaml.safe_dump(CONFIG), stats_dtype=STATS_DTYPE,
                   flush_interval_s=flush_interval_s, compression=compression,
                   float32_fields=float32_fields)
    s.start()
    time.sleep(1.0)                      # writer start-up (imports) before the paced loop
    n = len(records)
    push_ns = np.empty(n, np.int64)
    rec = np.zeros(1, RECORD_DTYPE)
    stats = np.zeros(1, STATS_DTYPE)
    t0 = time.monotonic()
    pc = time.perf_counter_ns
    for i in range(n):
        rec[0] = records[i]
        a = pc()
        s.push(rec)
        push_ns[i] = pc() - a
        if i % int(rate_hz) == 0:
            stats["t_s"], stats["cycles"] = records["t_s"][i], i
            s.push_stats(stats)
        delay = t0 + (i + 1) / rate_hz - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    wall = time.monotonic() - t0
    dropped = s.dropped
    code = s.close(timeout_s=30)
    files = sorted(out_dir.glob("capstan_*.mcap"))
    size = sum(f.stat().st_size for f in files)
    return {"n": n, "wall_s": wall, "push_us": push_ns / 1e3, "dropped": dropped, "exit": code,
            "bytes": size, "files": files}


def writer_throughput(records: np.ndarray, out_dir: Path, compression: str) -> float:
    """Records/s the writer loop drains from a pre-filled ring (in-process)."""
    ring = LogRing.create(RECORD_DTYPE, len(records) + 1, meta={"config_yaml": ""})
    for i in range(len(records)):
        ring.push(records[i])
    ring.close_producer()
    t0 = time.perf_counter()
    run_writer(ring, out_dir, compression=compression, prefix="throughput")
    dt = time.perf_counter() - t0
    ring.close()
    return len(records) / dt


def main() -> int:
    """Run the benchmark and print the figures."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--rate-hz", type=float, default=1000.0)
    p.add_argument("--flush-interval-s", type=float, default=0.5)
    p.add_argument("--compression", default="zstd", choices=("zstd", "lz4", "none"))
    p.add_argument("--out-dir", help="keep the logs here (default: a temporary directory)")
    p.add_argument("--float32-intermediates", action="store_true",
                   help="store the step's float intermediates (not tau_m_cmd_Nm) as float32")
    args = p.parse_args()
    n = int(args.seconds * args.rate_hz)
    f32 = tuple(f for f in STEP_OUTPUT_FIELDS if f != "tau_m_cmd_Nm" and RECORD_DTYPE[f] == np.float64) \
        if args.float32_intermediates else ()
    print(f"load average before: {os.getloadavg()[0]:.2f} (2 vCPU; other work inflates latencies)")
    t0 = time.perf_counter()
    recs = realistic_records(n)
    print(f"generated {n} realistic records ({RECORD_DTYPE.itemsize} B each raw, "
          f"{len(RECORD_DTYPE.names)} fields) in {time.perf_counter() - t0:.1f} s")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out_dir) if args.out_dir else Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        r = live_run(recs, args.rate_hz, out / "live", args.flush_interval_s, args.compression, f32)
        us = r["push_us"]
        bpr = r["bytes"] / n
        print(f"live run: {n} records at {args.rate_hz:.0f} Hz over {r['wall_s']:.1f} s, "
              f"writer exit {r['exit']}, {len(r['files'])} file(s)")
        print(f"  push: median {np.median(us):.2f} us, p99 {np.percentile(us, 99):.2f} us, "
              f"p99.9 {np.percentile(us, 99.9):.2f} us, max {us.max():.1f} us")
        print(f"  dropped: {r['dropped']}")
        print(f"  file: {r['bytes']} B = {bpr:.1f} B/record (compression {args.compression}, "
              f"chunk every {args.flush_interval_s} s, float32 fields: {', '.join(f32) or 'none'})")
        print(f"  MB/hour at {args.rate_hz:.0f} Hz: {bpr * args.rate_hz * 3600 / 1e6:.1f} "
              f"(extrapolated linearly from {args.seconds:.0f} s)")
        data = read_log(r["files"][0])
        exact = all(data.records[f].tobytes() == recs[f].tobytes() for f in RECORD_DTYPE.names if f not in f32)
        print(f"  read back: {len(data.records)} records, bit-identical (except float32 fields): {exact}")
        thr = writer_throughput(recs[: min(n, 100_000)], out / "thr", args.compression)
        print(f"writer throughput: {thr:,.0f} records/s ({thr / args.rate_hz:.0f}x the loop rate)")
        from tools.replay_cmd import build_controller, replay_records
        t1 = time.perf_counter()
        d2 = read_log(r["files"][0])
        ctl = build_controller(d2.config)
        res = replay_records(d2.records, ctl, ("cycle", *MEASUREMENT_FIELDS), STEP_OUTPUT_FIELDS)
        wall = time.perf_counter() - t1
        dur = float(d2.records["t_s"][-1] - d2.records["t_s"][0])
        print(f"replay: {len(d2.records)} cycles ({dur:.1f} s of log) in {wall:.2f} s = "
              f"{dur / wall:.0f}x real time (read {wall - res.wall_s:.2f} s + step {res.wall_s:.2f} s), "
              f"max |dtau_m| = {res.max_abs_dtau_m_Nm}")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
