"""Benchmark of the logging path (run on demand, prints figures; not a test).

    .venv/bin/python -m capstan.tools.bench.logs [--seconds 60] [--rate-hz 1000] [--levels 3,9,15,19]

1. live run: a 1 kHz paced producer pushes realistic cycle records (the real
   controller stepping on sensor values made the way the drivers make them) into a
   :class:`capstan.controller.log.writer.LogSession` laid out as the daemon's; prints µs per push
   (median, p99, max), dropped records, the writer process's CPU, bytes per record and
   MB per hour (extrapolated from the run), and the bytes per record of each field
   group (what each costs after compression, measured by leaving it out);
2. writer throughput: a pre-filled ring drained by the writer loop in-process
   (records/s it sustains, i.e. its margin over 1 kHz);
3. replay speed and exactness on the log of the live run (read + step, x real time);
4. with ``--levels``: file size and compression CPU per record for each zstd level.
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from capstan.controller.law.config import ControllerConfig
from capstan.controller.law.core import Controller
from capstan.controller.runtime.session_log import STATS_DTYPE
from capstan.controller.log.reader import read_log
from capstan.controller.log.ring import LogRing
from capstan.controller.log.writer import LIVE_ZSTD_LEVEL, LogSession, run_writer
from capstan.controller.log.mcap_log import DEFAULT_FLUSH_INTERVAL_S, McapLog
from capstan.controller.law.records import (LOG_FLOAT32_FIELDS, LOG_FLOAT32_QUANTA, MEASUREMENT_FIELDS, RECORD_DTYPE, STEP_OUTPUT_FIELDS,
                                loop_command)
from capstan.controller.law.records import DERIVED_FROM_WIRE
from capstan.controller.log.mcap_log import DERIVATIONS_META
from capstan.drivers.serial.xsens import twist_angle_rad, wrap_pi
from capstan.models.common.wire_units import NS_TO_S, Derivation, motor_torque_ops, scale_ops, tension_ops
from capstan.tools.bench.log_floor import WireScales, floor_table

#: limits raised so the open-loop synthetic run never saturates or faults: the command
#: stays a noisy float (the worst case for compression)
CONFIG = {"controller": {"feedback": {"kp": 4.0},
                         "safety": {"tau_max_Nm": 1000.0, "tau_fault_Nm": 2000.0,
                                    "dtau_max_Nm_s": 1e6, "dtau_fault_Nm_s": 1e7}}}

#: sensor scales as on the rig (config/serial_devices.yaml, config/motor.yaml, config/hil.yaml)
LC_SCALE_N_PER_MV_V = 250.0
RAD_PER_COUNT = 2 * math.pi / 131072 / 1.0            # capstan_drive.eds 0x6064 unit (DriveUnits)
RAD_S_PER_UNIT = 2 * math.pi / 131072 / 1.0           # capstan_drive.eds 0x606C unit (DriveUnits)
RATED_TORQUE_NM = 20.0
#: sensor noise as the simulated rig's (config/hil.yaml plant.noise) and drive feedback
NOISE_TENSION_N, NOISE_ANGLE_RAD, NOISE_RATE_RAD_S = 0.3, 5e-4, 2e-3
NOISE_DQ_M_RAD_S, NOISE_TAU_M_NM = 1e-3, 0.05


#: the conversions the drivers would publish for the scales above (the live run stores
#: wire values only, as the daemon does)
WIRE_DERIVATIONS = [
    Derivation("t_s", "t_ns", NS_TO_S), Derivation("lc_t_s", "lc_t_ns", NS_TO_S),
    Derivation("imu_t_s", "imu_t_ns", NS_TO_S), Derivation("motor_t_s", "motor_t_ns", NS_TO_S),
    *(Derivation(f, src, tension_ops(LC_SCALE_N_PER_MV_V, 0.0, 0.0)) for f, src in (
        ("T_up_in_N", "lc_up_in_mV_V"), ("T_up_out_N", "lc_up_out_mV_V"),
        ("T_lo_out_N", "lc_lo_out_mV_V"), ("T_lo_in_N", "lc_lo_in_mV_V"))),
    Derivation("dq_out_rad_s", "imu_rate_rad_s", scale_ops(1.0)),
    Derivation("q_m_rad", "q_m_counts", scale_ops(RAD_PER_COUNT)),
    Derivation("dq_m_rad_s", "dq_m_units", scale_ops(RAD_S_PER_UNIT)),
    Derivation("tau_m_meas_Nm", "tau_m_meas_permille", motor_torque_ops(RATED_TORQUE_NM)),
]


def realistic_records(n: int, seed: int = 7) -> np.ndarray:
    """Cycle records of a live-like run, each value made as the loop and drivers make it.

    Torque 3 Nm at 0.5 Hz + 0.3 Nm at 3.1 Hz with the link swinging 0.4 rad (more motion
    than a hand-guided HIL run, so more distinct values); the real controller steps.

    * loop time: an integer-ns wake-up (1 ms + 2 us + |N(0, 3 us)| latency) times 1e-9;
      ``period_s``/``compute_s`` are integer-ns differences times 1e-9;
    * load cells: one frame per cycle of four big-endian float32 bridge signals [mV/V]
      (0.3 N noise), ``T = scale * raw + offset - tare`` (scale 250, offset and tare 0),
      received (``time.monotonic()``, i.e. ns / 1e9) 20-60 us after the wake-up;
    * IMU at 400 Hz (2 of 5 cycles): a float32 quaternion about z, ``q_out`` its twist
      angle (float64 arithmetic), ``dq_out`` the float32 rate of turn; held in between;
    * drive: int32 position counts, int32 velocity units and int16 torque per mille of
      the rated torque, times their scales; CAN receive time = wall-clock float + an
      offset to the monotonic clock, as the CANopen driver computes it;
    * ``tau_out_ref_Nm`` 0 (the daemon never sets it); phase running, command through
      :func:`capstan.controller.law.records.loop_command` as in the loop.
    """
    rng = np.random.default_rng(seed)
    ctl = Controller(ControllerConfig.from_mapping(CONFIG["controller"]))
    ctl.warmup()
    out = np.zeros(n, RECORD_DTYPE)
    rec = ctl.record[0]
    wall_minus_mono_ns = 1_763_000_000_000_000_000 - 1_000_000_000_000
    deadline = prev_wake = 1_000_000_000_000                  # monotonic ns (1000 s uptime)
    for k in range(n):
        deadline += 1_000_000
        wake = deadline + 2_000 + int(abs(rng.normal(0, 3_000)))
        ph = 2 * np.pi * 0.5 * k * 1e-3
        tau = 3.0 * np.sin(ph) + 0.3 * np.sin(6.2 * ph)
        rec["cycle"], rec["t_s"], rec["t_ns"] = k, wake * 1e-9, wake
        raw = np.array([150 + tau / 0.08, 146 + 0.9 * tau / 0.08, 146 - 0.9 * tau / 0.08, 150 - tau / 0.08])
        raw = ((raw + rng.normal(0, NOISE_TENSION_N, 4)) / LC_SCALE_N_PER_MV_V).astype(">f4").tolist()
        rec["T_up_in_N"], rec["T_up_out_N"], rec["T_lo_out_N"], rec["T_lo_in_N"] = (
            LC_SCALE_N_PER_MV_V * x + 0.0 - 0.0 for x in raw)
        rec["lc_up_in_mV_V"], rec["lc_up_out_mV_V"], rec["lc_lo_out_mV_V"], rec["lc_lo_in_mV_V"] = raw
        rec["lc_t_ns"] = wake + int(rng.uniform(20_000, 60_000))
        rec["lc_t_s"] = rec["lc_t_ns"] * 1e-9
        if k % 5 in (0, 2):
            half = 0.5 * (0.4 * np.sin(ph - 0.3) + rng.normal(0, NOISE_ANGLE_RAD))
            quat = np.array([np.cos(half), 0.0, 0.0, np.sin(half)], ">f4").tolist()
            rec["q_out_rad"] = wrap_pi(1.0 * twist_angle_rad(quat, 2) + 0.0)
            rec["imu_rate_rad_s"] = float(np.float32(0.4 * np.pi * np.cos(ph - 0.3)
                                                     + rng.normal(0, NOISE_RATE_RAD_S)))
            rec["dq_out_rad_s"] = 1.0 * rec["imu_rate_rad_s"]
            rec["imu_t_ns"] = wake + int(rng.uniform(60_000, 90_000))
            rec["imu_t_s"] = rec["imu_t_ns"] * 1e-9
            rec["imu_new"] = 1
        else:
            rec["imu_new"] = 0
        counts = int(round(0.41 * np.sin(ph - 0.25) / RAD_PER_COUNT))
        vel = int(round((0.41 * np.pi * np.cos(ph - 0.25) + rng.normal(0, NOISE_DQ_M_RAD_S)) / RAD_S_PER_UNIT))
        permille = int(round((tau + rng.normal(0, NOISE_TAU_M_NM)) * 1000.0 / RATED_TORQUE_NM))
        rec["q_m_rad"] = counts * RAD_PER_COUNT
        rec["dq_m_rad_s"] = vel * RAD_S_PER_UNIT
        rec["tau_m_meas_Nm"] = permille * RATED_TORQUE_NM / 1000.0
        rx_mono_ns = wake - int(rng.uniform(100_000, 400_000))
        to_mono = (wake + 5_000) / 1e9 - (wake + 5_000 + wall_minus_mono_ns) / 1e9
        rec["motor_t_ns"] = round(((rx_mono_ns + wall_minus_mono_ns) / 1e9 + to_mono) * 1e9)
        rec["motor_t_s"] = rec["motor_t_ns"] * 1e-9
        rec["q_m_counts"], rec["dq_m_units"], rec["tau_m_meas_permille"] = counts, vel, permille
        rec["tau_out_ref_Nm"] = 0.0
        rec["phase"], rec["cmd_scale"] = 1, 1.0
        tau_cmd = loop_command(ctl.step(), 1.0, int(rec["fault_bits"]))
        rec["tau_m_cmd_Nm"] = tau_cmd
        done = wake + 60_000 + int(abs(rng.normal(0, 15_000)))
        rec["period_s"] = (wake - prev_wake) * 1e-9
        rec["compute_s"] = (done - wake) * 1e-9
        rec["late"] = 0
        prev_wake = wake
        out[k] = rec
    return out


def _quanta(float32_fields: tuple[str, ...]) -> dict[str, float]:
    """The daemon's quanta (:data:`LOG_FLOAT32_QUANTA`) of those of ``float32_fields`` it rounds."""
    return {f: q for f, q in LOG_FLOAT32_QUANTA.items() if f in float32_fields}


def live_run(records: np.ndarray, rate_hz: float, out_dir: Path, flush_interval_s: float,
             compression: str, float32_fields: tuple[str, ...], zstd_level: int) -> dict:
    """Push ``records`` at ``rate_hz`` into a LogSession; returns the figures (the
    writer's CPU time from the children's rusage: the writer is this process's only child)."""
    s = LogSession(RECORD_DTYPE, out_dir, yaml.safe_dump(CONFIG), stats_dtype=STATS_DTYPE,
                   flush_interval_s=flush_interval_s, compression=compression,
                   float32_fields=float32_fields + ("imu_rate_rad_s",), zstd_level=zstd_level,
                   drop_fields=tuple(DERIVED_FROM_WIRE), float32_quanta=_quanta(float32_fields))
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    s.start()
    s.metadata(DERIVATIONS_META, {"derivations": [d.to_json() for d in WIRE_DERIVATIONS]})
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
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    files = sorted(out_dir.glob("capstan_*.mcap"))
    size = sum(f.stat().st_size for f in files)
    return {"n": n, "wall_s": wall, "push_us": push_ns / 1e3, "dropped": dropped, "exit": code,
            "bytes": size, "files": files,
            "writer_cpu_s": (cpu1.ru_utime + cpu1.ru_stime) - (cpu0.ru_utime + cpu0.ru_stime)}


def file_bytes(records: np.ndarray, out_dir: Path, float32_fields: tuple[str, ...], zstd_level: int,
               chunk_records: int, compression: str = "zstd") -> tuple[int, float]:
    """(file size [B], CPU [s]) of ``records`` written in-process in chunks of
    ``chunk_records`` (the live writer's chunks at 1 kHz and its flush interval)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.process_time()
    log = McapLog(out_dir, "offline", records.dtype, yaml.safe_dump(CONFIG), flush_interval_s=0,
                  compression=compression, zstd_level=zstd_level,
                  float32_fields=tuple(f for f in float32_fields if f in records.dtype.names),
                  float32_quanta=_quanta(tuple(f for f in float32_fields if f in records.dtype.names)),
                  # wire layout: t_s gives the message times but is not stored (t_ns is)
                  drop_fields=("t_s",) if "lc_t_ns" in records.dtype.names else ())
    for i in range(0, len(records), chunk_records):
        log.write_records(records[i:i + chunk_records])
        log.flush()
    log.close()
    cpu = time.process_time() - t0
    size = log.current_file.stat().st_size
    log.current_file.unlink()
    return size, cpu


#: field groups whose cost is reported (bytes per record when the group is left out)
FIELD_GROUPS: dict[str, tuple[str, ...]] = {
    "cycle, flags, gating": ("cycle", "imu_new", "ext_fault_bits", "tau_out_ref_Nm", "fault_bits", "late",
                             "phase", "cmd_scale"),
    "loop time t_ns": ("t_ns",),
    "load cells (4 bridge signals, receive time)": ("T_up_in_N", "T_up_out_N", "T_lo_out_N", "T_lo_in_N", "lc_t_s",
                                                    "lc_up_in_mV_V", "lc_up_out_mV_V", "lc_lo_out_mV_V",
                                                    "lc_lo_in_mV_V", "lc_t_ns"),
    "IMU (q_out, rate, receive time)": ("q_out_rad", "dq_out_rad_s", "imu_t_s", "imu_rate_rad_s", "imu_t_ns"),
    "drive feedback (counts, units, per mille, receive time)": ("q_m_rad", "dq_m_rad_s", "tau_m_meas_Nm", "motor_t_s",
                                                                "q_m_counts", "dq_m_units", "tau_m_meas_permille",
                                                                "motor_t_ns"),
    "step intermediates and state": ("tau_in_Nm", "T0_meas_N", "tau_g_Nm", "tau_fc_Nm", "tau_in_des_Nm",
                                     "err_Nm", "pd_Nm", "d_hat_Nm", "tau_m_raw_Nm"),
    "command tau_m_cmd_Nm": ("tau_m_cmd_Nm",),
    "timing (period, compute)": ("period_s", "compute_s"),
}


def group_costs(records: np.ndarray, out_dir: Path, float32_fields: tuple[str, ...], zstd_level: int,
                chunk_records: int) -> dict[str, float]:
    """Bytes per record each :data:`FIELD_GROUPS` group adds to the file (size with all
    fields minus size without the group), plus ``"all"`` and the message framing (a file
    of messages holding ``t_s`` alone: record header, message-index entry, ``t_s``)."""
    n = len(records)
    full, _ = file_bytes(records, out_dir, float32_fields, zstd_level, chunk_records)
    out = {"all": full / n}
    for label, names in FIELD_GROUPS.items():
        keep = [f for f in records.dtype.names if f not in names]
        part = np.zeros(n, np.dtype([(f, records.dtype[f]) for f in keep]))
        for f in keep:
            part[f] = records[f]
        size, _ = file_bytes(part, out_dir, float32_fields, zstd_level, chunk_records)
        out[label] = (full - size) / n
    only_t = np.zeros(n, np.dtype([("t_s", "<f8")]))
    only_t["t_s"] = records["t_s"]
    size_t, _ = file_bytes(only_t, out_dir, (), zstd_level, chunk_records)
    out["message framing (record header, index entry, t_s)"] = size_t / n
    return out


def writer_throughput(records: np.ndarray, out_dir: Path, compression: str, float32_fields: tuple[str, ...],
                      zstd_level: int) -> float:
    """Records/s the writer loop drains from a pre-filled ring (in-process)."""
    ring = LogRing.create(RECORD_DTYPE, len(records) + 1, meta={"config_yaml": ""})
    for i in range(len(records)):
        ring.push(records[i])
    ring.close_producer()
    t0 = time.perf_counter()
    run_writer(ring, out_dir, compression=compression, prefix="throughput", float32_fields=float32_fields,
               zstd_level=zstd_level)
    dt = time.perf_counter() - t0
    ring.close()
    return len(records) / dt


def main() -> int:
    """Run the benchmark and print the figures."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--rate-hz", type=float, default=1000.0)
    p.add_argument("--flush-interval-s", type=float, default=DEFAULT_FLUSH_INTERVAL_S)
    p.add_argument("--compression", default="zstd", choices=("zstd", "lz4", "none"))
    p.add_argument("--zstd-level", type=int, default=LIVE_ZSTD_LEVEL)
    p.add_argument("--all-float64", action="store_true",
                   help="store every float field as float64 (not the daemon's LOG_FLOAT32_FIELDS)")
    p.add_argument("--levels", default="", help="comma-separated zstd levels for an offline size/CPU table")
    p.add_argument("--out-dir", help="keep the logs here (default: a temporary directory)")
    p.add_argument("--floor", action="store_true",
                   help="only print per-field compressed costs under columnar and fixed-point layouts "
                        "(tools/bench/log_floor.py) and exit")
    args = p.parse_args()
    n = int(args.seconds * args.rate_hz)
    f32 = () if args.all_float64 else LOG_FLOAT32_FIELDS
    chunk_records = max(1, int(round(args.flush_interval_s * args.rate_hz)))
    print(f"load average before: {os.getloadavg()[0]:.2f} (2 vCPU; other work inflates latencies)")
    t0 = time.perf_counter()
    recs = realistic_records(n)
    print(f"generated {n} realistic records ({RECORD_DTYPE.itemsize} B each raw, "
          f"{len(RECORD_DTYPE.names)} fields) in {time.perf_counter() - t0:.1f} s")
    if args.floor:
        scales = WireScales(LC_SCALE_N_PER_MV_V, RAD_PER_COUNT, RAD_S_PER_UNIT, RATED_TORQUE_NM)
        print(f"per-field bytes per record, columnar zstd {args.zstd_level}, {chunk_records}-record chunks "
              "(as logged now -> fixed point):")
        for label, b in floor_table(recs, f32, scales, chunk_records, args.zstd_level):
            extra = f" = {b * args.rate_hz * 3600 / 1e6:.0f} MB/hour" if label.startswith("TOTAL") else ""
            print(f"{label}{extra}")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out_dir) if args.out_dir else Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        r = live_run(recs, args.rate_hz, out / "live", args.flush_interval_s, args.compression, f32,
                     args.zstd_level)
        us = r["push_us"]
        bpr = r["bytes"] / n
        print(f"live run: {n} records at {args.rate_hz:.0f} Hz over {r['wall_s']:.1f} s, "
              f"writer exit {r['exit']}, {len(r['files'])} file(s)")
        print(f"  push: median {np.median(us):.2f} us, p99 {np.percentile(us, 99):.2f} us, "
              f"p99.9 {np.percentile(us, 99.9):.2f} us, max {us.max():.1f} us")
        print(f"  dropped: {r['dropped']}")
        print(f"  writer process CPU: {r['writer_cpu_s']:.2f} s = "
              f"{100 * r['writer_cpu_s'] / (r['wall_s'] + 1.0):.1f} % of one CPU (incl. 1 s start-up)")
        print(f"  file: {r['bytes']} B = {bpr:.1f} B/record (compression {args.compression} level "
              f"{args.zstd_level}, chunk every {args.flush_interval_s} s, float32 fields: "
              f"{', '.join(f32) or 'none'})")
        print(f"  MB/hour at {args.rate_hz:.0f} Hz: {bpr * args.rate_hz * 3600 / 1e6:.1f} "
              f"(extrapolated linearly from {args.seconds:.0f} s)")
        data = read_log(r["files"][0])
        exact = all(data.records[f].tobytes() == recs[f].tobytes() for f in RECORD_DTYPE.names if f not in f32)
        print(f"  read back: {len(data.records)} records, bit-identical (except float32 fields): {exact}")
        # the offline figures below use the stored (wire) layout of the live log
        stored = np.zeros(n, np.dtype([(f, RECORD_DTYPE[f]) for f in RECORD_DTYPE.names if f not in DERIVED_FROM_WIRE]))
        for f in stored.dtype.names:
            stored[f] = recs[f]
        stored_t = np.zeros(n, np.dtype(stored.dtype.descr + [("t_s", "<f8")]))
        for f in stored.dtype.names:
            stored_t[f] = stored[f]
        stored_t["t_s"] = recs["t_s"]              # message times (not stored in the payload by the daemon)
        costs = group_costs(stored_t, out / "groups", f32 + ("imu_rate_rad_s",), args.zstd_level, chunk_records)
        print("  bytes per record by field group (file size with minus without the group):")
        for label, b in costs.items():
            print(f"    {label:48s} {b:6.1f}")
        thr = writer_throughput(recs[: min(n, 100_000)], out / "thr", args.compression, f32, args.zstd_level)
        print(f"writer throughput: {thr:,.0f} records/s ({thr / args.rate_hz:.0f}x the loop rate)")
        from capstan.tools.offline.replay import build_controller, replay_records
        t1 = time.perf_counter()
        d2 = read_log(r["files"][0])
        ctl = build_controller(d2.config)
        res = replay_records(d2.records, ctl, ("cycle", *MEASUREMENT_FIELDS), STEP_OUTPUT_FIELDS)
        wall = time.perf_counter() - t1
        dur = float(d2.records["t_s"][-1] - d2.records["t_s"][0])
        print(f"replay: {len(d2.records)} cycles ({dur:.1f} s of log) in {wall:.2f} s = "
              f"{dur / wall:.0f}x real time (read {wall - res.wall_s:.2f} s + step {res.wall_s:.2f} s), "
              f"max |dtau_m| = {res.max_abs_dtau_m_Nm}")
        for level in (int(x) for x in args.levels.split(",") if x.strip()):
            size, cpu = file_bytes(stored_t, out / "levels", f32 + ("imu_rate_rad_s",), level, chunk_records)
            print(f"zstd level {level:2d}: {size / n:6.1f} B/record = "
                  f"{size / n * args.rate_hz * 3600 / 1e6:6.1f} MB/hour, writing {cpu / n * 1e6:5.1f} us "
                  f"CPU/record ({100 * cpu / n * args.rate_hz:.1f} % of one CPU)")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
