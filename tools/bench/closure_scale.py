"""Benchmark of the streamed closure over hours of 1 kHz data (``capstan close --stream`` /
``--workers N``: :mod:`capstan.tools.offline.closure_stream`). Prints, per length and
number of workers, the wall time of the whole job, the peak resident memory of the driver
and of the whole process tree (driver + Dask scheduler + workers, sampled every 0.2 s), the
selections and the held-out RMSE on every sample.

``python -m capstan.tools.bench.closure_scale --hours 1 2 --workers 0 1 2`` (0 workers: the
tasks in the driver's process, one run at a time; -1: not streamed, every sample in memory as
``capstan close`` without ``--stream``, for the selections). The data are the runs of
:func:`capstan.tools.bench.closure.synthetic_run` (the testbed plant with a friction that grows
along the angle), ``--piece-minutes`` long each as a rig's rotated log files, each with its
own seed, synthesised inside the task that reads it (no disk; the first 70 % of the pieces
train, the rest are held out). Each case runs in its own process so its peak memory is its own.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from typing import Sequence

from capstan.models.common.measurement_table import MeasurementTable


@dataclass(frozen=True)
class SyntheticPiece:
    """One synthetic log file: ``minutes`` of :func:`capstan.tools.bench.closure.synthetic_run`."""

    minutes: float
    seed: int
    position_gain: float = 0.3

    def table(self) -> MeasurementTable:
        from capstan.tools.bench.closure import synthetic_run

        tb = synthetic_run(self.minutes, self.seed, self.position_gain)
        tb.source = f"synthetic seed {self.seed}"
        return tb


class TreeRss:
    """Peak of the summed RSS of this process and its descendants, sampled in a thread."""

    def __init__(self, period_s: float = 0.2) -> None:
        import psutil

        self._me = psutil.Process()
        self.peak_B = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(period_s,), daemon=True)
        self._thread.start()

    def _run(self, period_s: float) -> None:
        while not self._stop.is_set():
            total = 0
            for p in [self._me] + self._me.children(recursive=True):
                try:
                    total += p.memory_info().rss
                except Exception:       # a process that just ended
                    pass
            self.peak_B = max(self.peak_B, total)
            self._stop.wait(period_s)

    def stop(self) -> int:
        self._stop.set()
        self._thread.join()
        return self.peak_B


def in_memory(hours: float, piece_minutes: float) -> dict:
    """The same pieces closed in memory (``capstan close`` without ``--stream``), for the selections."""
    from capstan.models.closure.pipeline import close
    from capstan.models.closure.signals import signals_from_tables

    n, k = _pieces(hours, piece_minutes)
    t0 = time.perf_counter()
    sig = signals_from_tables([SyntheticPiece(piece_minutes, seed).table() for seed in range(n)])
    res = close(sig.take(sig.run_id < k), sig.take(sig.run_id >= k))
    main = next(iter(res.targets.values()))
    return {"hours": hours, "workers": "in memory", "pieces": n, "samples": {"train": 0, "test": len(sig)},
            "wall_s": time.perf_counter() - t0, "cluster_start_s": 0.0, "timings_s": res.timings_s,
            "driver_rss_MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3,
            "tree_rss_MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3,
            "selected": [c.effect for c in main.selected], "window_samples": "every sample",
            "rmse_every_sample_Nm": (main.rmse_before_Nm, main.rmse_after_Nm)}


def _pieces(hours: float, piece_minutes: float) -> tuple[int, int]:
    """(pieces, training pieces: the first 70 %)."""
    n = max(2, int(round(60.0 * hours / piece_minutes)))
    return n, max(1, min(n - 1, int(round(0.7 * n))))


def one_case(hours: float, workers: int, piece_minutes: float) -> dict:
    """Close ``hours`` of synthetic pieces with ``workers`` Dask workers (0: in process; -1:
    every sample in memory, not streamed)."""
    from capstan.tools.offline.closure_stream import DaskMapper, Piece, close_streamed, in_process

    if workers < 0:
        return in_memory(hours, piece_minutes)
    n, k = _pieces(hours, piece_minutes)
    srcs = [Piece(SyntheticPiece(piece_minutes, seed)) for seed in range(n)]
    rss = TreeRss()
    t0 = time.perf_counter()
    mapper = DaskMapper(workers) if workers else None
    t1 = time.perf_counter()
    try:
        out = close_streamed(srcs[:k], srcs[k:], mapper or in_process)
    finally:
        if mapper is not None:
            mapper.close()
    wall = time.perf_counter() - t0
    tree = rss.stop()
    main = next(iter(out.result.targets.values()))
    b, f = out.every_sample if out.every_sample else (None, None)
    return {"hours": hours, "workers": workers, "pieces": n, "samples": out.samples, "wall_s": wall,
            "cluster_start_s": t1 - t0, "timings_s": out.result.timings_s, "passes_s": out.timings_s,
            "driver_rss_MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3, "tree_rss_MB": tree / 1e6,
            "selected": [c.effect for c in main.selected], "window_samples": out.window_samples,
            "rmse_every_sample_Nm": None if f is None else (b.rmse_Nm, f.rmse_Nm)}


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, nargs="+", default=[1.0])
    ap.add_argument("--workers", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--piece-minutes", type=float, default=10.0, help="length of one log file [min]")
    ap.add_argument("--one", nargs=2, type=float, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one is not None:
        print(json.dumps(one_case(args.one[0], int(args.one[1]), args.piece_minutes), default=float))
        return 0
    for h in args.hours:
        for w in args.workers:
            cmd = [sys.executable, "-m", "capstan.tools.bench.closure_scale", "--one", str(h), str(w),
                   "--piece-minutes", str(args.piece_minutes)]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                sys.stderr.write(proc.stderr)
                return proc.returncode
            r = json.loads(proc.stdout.strip().splitlines()[-1])
            ts = r["timings_s"]
            rm = r["rmse_every_sample_Nm"]
            print(f"{h:4.1f} h {r['samples']['train'] + r['samples']['test']:9d} samples ({r['pieces']} pieces), "
                  f"{w if w >= 0 else 'no'} workers{'' if w >= 0 else ' (in memory)'}: wall {r['wall_s']:6.1f} s (cluster start {r['cluster_start_s']:.1f} s; closure on "
                  f"windows: baseline {ts.get('baseline', 0):.1f}, candidates {ts.get('candidates', 0):.1f} s)  "
                  f"peak RSS driver {r['driver_rss_MB']:6.0f} MB, all processes {r['tree_rss_MB']:6.0f} MB  "
                  f"windows {r['window_samples']}  selected {r['selected']}  every held-out sample RMSE "
                  f"{rm[0]:.4f} -> {rm[1]:.4f} Nm  passes {json.dumps({k: round(v, 1) for k, v in r.get('passes_s', {}).items()})}  load {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
