"""Benchmark of ``capstan replay`` on a long live log (run on demand, prints figures).

    .venv/bin/python -m capstan.tools.bench.replay_speed HIL_LOG.mcap [--minutes 10] [--runs 3]

1. builds a long log from a daemon log (a HIL run): the daemon log's cycles repeated
   until ``--minutes`` are covered, every integer-nanosecond time and the cycle number
   shifted so the log runs on, the SI inputs rebuilt from the wire values with the
   logged derivations, the controller's outputs recomputed by stepping the logged
   controller over the whole log (so the commands in the file are what this controller
   computes), and written through :class:`capstan.controller.log.mcap_log.McapLog` with
   the daemon's layout (the source log's stored fields, float32 fields, derivations
   metadata, the daemon's float32 quanta, zstd level, a chunk per 0.8 s of cycles);
2. runs ``capstan replay LOG --json`` ``--runs`` times in fresh processes and prints
   the median and the spread of the read time, the step time, x real time, and max
   |dtau_m| (must be 0); also the CPU seconds the replay process used for reading and
   stepping (x real time per CPU second: the figure on a machine with a core to spare)
   and the load average.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from capstan.controller.log.mcap_log import DERIVATIONS_META, McapLog
from capstan.controller.log.reader import read_log
from capstan.controller.log.session import LIVE_ZSTD_LEVEL
from capstan.models.common.wire_units import Derivation, apply_ops

#: integer-nanosecond time fields shifted from one repetition to the next
NS_FIELDS = ("t_ns", "lc_t_ns", "imu_t_ns", "motor_t_ns")
#: cycles per chunk (the daemon's writer flushes every 0.8 s at 1 kHz)
CHUNK_CYCLES = 800


def _stored_layout(path: Path) -> tuple[tuple[str, ...], tuple[str, ...], str]:
    """(float32 fields, derived fields, derivations JSON) of a live log's cycle channel."""
    from mcap.reader import make_reader
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        ch = next(c for c in reader.get_summary().channels.values() if c.topic == "/capstan/cycle")
        deriv = next((m.metadata["derivations"] for m in reader.iter_metadata() if m.name == DERIVATIONS_META), "")
    return (tuple(json.loads(ch.metadata.get("float32_fields", "[]"))),
            tuple(json.loads(ch.metadata.get("derived_fields", "[]"))), deriv)


def build_long_log(src: Path, out: Path, minutes: float) -> dict:
    """Write the long log (step 1 of the module doc); returns its figures."""
    from capstan.controller.law.records import LOG_FLOAT32_QUANTA, MEASUREMENT_FIELDS, STEP_OUTPUT_FIELDS
    from capstan.tools.offline.replay import build_controller, replay_records

    data = read_log(src)
    f32, derived, deriv_json = _stored_layout(src)
    base = data.records
    n0 = len(base)
    span_ns = int(base["t_ns"][-1] - base["t_ns"][0]) + int(np.median(np.diff(base["t_ns"])))
    reps = int(np.ceil(minutes * 60e9 / span_ns))
    recs = np.concatenate([base] * reps)
    k = np.repeat(np.arange(reps, dtype=np.int64), n0)
    for name in NS_FIELDS:
        recs[name] += k * span_ns
    recs["cycle"] += (k * n0).astype(recs["cycle"].dtype)
    for d in (Derivation.from_json(x) for x in json.loads(deriv_json)):
        recs[d.field] = apply_ops(recs[d.source].astype(np.float64), d.ops)
    ctl = build_controller(data.config)
    inputs = tuple(f for f in ("cycle", *MEASUREMENT_FIELDS) if f in ctl.record.dtype.names)
    res = replay_records(recs, ctl, inputs, STEP_OUTPUT_FIELDS)
    recs = res.replayed
    out.parent.mkdir(parents=True, exist_ok=True)
    log = McapLog(out.parent, out.stem, recs.dtype, data.config_yaml,
                  stats_dtype=data.stats.dtype if data.stats is not None else None, flush_interval_s=0,
                  first_path=out, float32_fields=f32, zstd_level=LIVE_ZSTD_LEVEL, drop_fields=derived,
                  float32_quanta={f: q for f, q in LOG_FLOAT32_QUANTA.items() if f in f32})
    log.add_metadata(DERIVATIONS_META, {"derivations": deriv_json})
    stats = data.stats
    for i, a in enumerate(range(0, len(recs), CHUNK_CYCLES)):
        log.write_records(recs[a:a + CHUNK_CYCLES])
        if stats is not None and len(stats) and i % 2 == 0:        # about one per second
            row = stats[(i // 2) % len(stats):(i // 2) % len(stats) + 1].copy()
            if "t_s" in row.dtype.names:
                row["t_s"] = recs["t_s"][a]
            log.write_stats(row)
        log.flush()
    log.close()
    return {"cycles": len(recs), "duration_s": float(recs["t_s"][-1] - recs["t_s"][0]),
            "repetitions": reps, "bytes": out.stat().st_size, "source_cycles": n0}


def run_replays(path: Path, runs: int) -> list[dict]:
    """``capstan replay PATH --json`` ``runs`` times, each in a new process."""
    out = []
    for _ in range(runs):
        t0 = time.perf_counter()
        res = subprocess.run([sys.executable, "-m", "capstan.tools.cli", "replay", str(path), "--json"],
                             capture_output=True, text=True, check=False)
        wall = time.perf_counter() - t0
        if res.returncode != 0:
            raise RuntimeError(f"replay failed ({res.returncode}): {res.stderr[-2000:]}")
        rep = json.loads(res.stdout)
        rep["process_wall_s"] = wall
        out.append(rep)
    return out


def _each(reps: list[dict], key: str, fmt: str) -> str:
    return ", ".join(format(r[key], fmt) for r in reps)


def main() -> int:
    """Entry point: build the log, replay it, print the figures."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("source", help="a daemon (HIL) live log")
    p.add_argument("--minutes", type=float, default=10.0)
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--out", default="", help="long log path (default: SOURCE_long.mcap next to it)")
    p.add_argument("--reuse", action="store_true", help="replay an existing --out without rebuilding it")
    a = p.parse_args()
    src = Path(a.source)
    out = Path(a.out) if a.out else src.with_name(src.stem + "_long.mcap")
    if not (a.reuse and out.exists()):
        fig = build_long_log(src, out, a.minutes)
        print(f"long log {out}: {fig['cycles']} cycles, {fig['duration_s']:.1f} s, "
              f"{fig['bytes'] / 1e6:.1f} MB ({fig['repetitions']} x {fig['source_cycles']} cycles of {src.name})")
    a_load_before = os.getloadavg()[0]
    reps = run_replays(out, a.runs)
    med = {k: statistics.median(r[k] for r in reps)
           for k in ("read_wall_s", "step_wall_s", "speed_x_realtime", "process_wall_s", "decoder_load_s",
                     "controller_build_s", "read_cpu_s", "step_cpu_s", "speed_x_realtime_cpu")}
    dur = reps[0]["duration_s"]
    print(f"replay of {reps[0]['cycles']} cycles ({dur:.1f} s), {a.runs} runs: max |dtau_m| = "
          f"{max(r['max_abs_dtau_m_Nm'] for r in reps)} Nm, cycles different {max(r['cycles_different'] for r in reps)}")
    print(f"  read  median {med['read_wall_s']:.3f} s  ({_each(reps, 'read_wall_s', '.3f')})"
          f"  = {1e6 * med['read_wall_s'] / reps[0]['cycles']:.2f} us/cycle")
    print(f"  step  median {med['step_wall_s']:.3f} s  ({_each(reps, 'step_wall_s', '.3f')})"
          f"  = {1e6 * med['step_wall_s'] / reps[0]['cycles']:.2f} us/cycle")
    print(f"  x real time (duration / (read + step)): median {med['speed_x_realtime']:.0f} "
          f"({_each(reps, 'speed_x_realtime', '.0f')})")
    print(f"  CPU of the replay process: read median {med['read_cpu_s']:.3f} s, step {med['step_cpu_s']:.3f} s "
          f"-> x real time per CPU second (duration / (read + step CPU)): median "
          f"{med['speed_x_realtime_cpu']:.0f} ({_each(reps, 'speed_x_realtime_cpu', '.0f')}); "
          f"wall / CPU = {(med['read_wall_s'] + med['step_wall_s']) / (med['read_cpu_s'] + med['step_cpu_s']):.2f} "
          f"(> 1: the process waited for a CPU)")
    print(f"  load average {a_load_before:.2f} before, {os.getloadavg()[0]:.2f} after (2-core VM shared with other work)")
    print(f"  fixed start-up: controller build {med['controller_build_s']:.2f} s, decoder load "
          f"{med['decoder_load_s']:.2f} s; whole process median {med['process_wall_s']:.2f} s "
          f"= {dur / med['process_wall_s']:.0f}x real time end to end")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
