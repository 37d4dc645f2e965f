"""Benchmark of the whole model closure on every sample (``capstan close`` of one run split
70/30: static feedforward map, dynamic baseline, residual trace, in-model candidates,
report), for runs of growing length at 1 kHz. Prints, per length, the median wall time of
each stage and of the whole (over ``--repeat`` closures), the median cost of one simulation
of the whole run, and the peak resident memory of a fresh process; then the ratios against
the shortest length of the same invocation.

``python -m capstan.tools.bench.closure --minutes 1 5 15 60`` (the 60-minute run, the
issue's 3.6 M samples, is the target: <= 60 s on a shared 2-core machine). By default every
length goes through the long-run path (``--path long``), so the ratios compare one method;
``--path auto`` times what ``capstan close`` chooses (the short path below
``windows.WARM_START_SAMPLES`` training samples: Powell on every sample, minutes).

Each length runs in its own process (``--one``), so its peak memory is its own. The runs
are a testbed plant of the reduced family (declared environment, 0.02 Nm noise) with a
friction that grows along the output angle (``--effect``, so that the closure selects an
effect and refits it jointly on every sample, the expensive path): speed does not depend on
where the data come from. The timed closure excludes reading the run from disk.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from capstan.models.closure.dynamic.baseline import _predict

from capstan.models.closure.dynamic.forms import DrivingForm
from capstan.models.closure.pipeline import close, split_single
from capstan.models.closure.signals import signals_from_tables
from capstan.models.common.measurement_table import MeasurementTable
from capstan.models.transmission.stick_slip import simulate_unit

STAGES = ("signals", "feedforward", "baseline", "trace", "candidates", "report")


def synthetic_run(minutes: float, seed: int = 0, position_gain: float = 0.0) -> MeasurementTable:
    """A testbed run of ``minutes`` at 1 kHz: multisine drive, friction state, noise; the
    friction capacity times ``1 + position_gain * q_out / max|q_out|`` when the gain is set."""
    t = np.arange(0.0, 60.0 * minutes, 1e-3)
    rng = np.random.default_rng(seed)
    u = sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 6)) / (1 + k) for k, f in enumerate((0.11, 0.23, 0.41, 0.73)))
    u = 6.0 * u / np.max(np.abs(u))
    n = t.size
    x, v, f = np.empty(n), np.empty(n), np.empty(n)
    args = (t, u, np.array([0, n]), np.zeros(1), np.array([2.0]), np.array([20.0]), 2e5, 1.7, 1.1, 0.03, 0.02)
    simulate_unit(*args, x, v, f, np.empty(0), 0.0)
    span = max(float(np.max(np.abs(x))), 1e-9)
    for _ in range(3 if position_gain else 0):    # the capacity follows the angle (fixed point)
        cap = 1.0 + position_gain * x / span
        simulate_unit(*args, x, v, f, cap, 0.0)
    tau_out = 20.0 * x + 2.0 * v
    cols = {"t": t, "tau_in": u + 0.02 * rng.standard_normal(n), "tau_out": tau_out + 0.02 * rng.standard_normal(n),
            "q_out": x, "dq_out": v + 1e-3 * rng.standard_normal(n)}
    return MeasurementTable(cols, {"environment": {"k_out": 20.0, "b_out": 2.0}}, f"synthetic {minutes} min")


def one_length(minutes: float, repeat: int, position_gain: float, long_path: bool = False) -> dict:
    """Time the closure of one synthetic run of ``minutes`` (stages, whole, simulation);
    ``long_path``: the long-run path even below ``windows.WARM_START_SAMPLES``."""
    from capstan.models.closure import windows
    from capstan.tools.offline.closure_report import summary, write_report

    if long_path:
        windows.WARM_START_SAMPLES = 0

    table = synthetic_run(minutes, position_gain=position_gain)
    out: dict = {"minutes": minutes, "stages": {k: [] for k in STAGES}, "total": [], "selected": []}
    for _ in range(repeat):
        t0 = time.perf_counter()
        sig = signals_from_tables([table])
        train, test = split_single(sig)
        t1 = time.perf_counter()
        res = close(train, test)
        t2 = time.perf_counter()
        with tempfile.TemporaryDirectory() as d:
            summ = summary(res, ["train"], ["test"], "reduced")
            write_report(res, summ, Path(d), [])
        t3 = time.perf_counter()
        st = {"signals": t1 - t0, **res.timings_s, "report": t3 - t2}
        if res.dynamic is not None:
            for k in ("screen", "held-out", "joint", "joint-scored"):
                out["stages"].setdefault(k, []).append(res.dynamic.timings_s.get(k, 0.0))
        for k in STAGES:
            out["stages"][k].append(st.get(k, 0.0))
        out["total"].append(t3 - t0)
        out["selected"] = [s["effect"] for s in summ["selected"]]
        out["rmse"] = (summ["baseline"]["rmse_Nm"], summ["final"]["rmse_Nm"])
    n = len(sig)
    p = np.array([20.0, 2.0, 1.7, 2e5, 1.1, 0.03, 0.02, 0.0])
    sims = []
    for _ in range(3):
        t0 = time.perf_counter()
        _predict(DrivingForm.TESTBED, p, sig, True)
        sims.append(time.perf_counter() - t0)
    out.update(samples=n, simulation=float(np.median(sims)),
               rss_MB=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, nargs="+", default=[1.0, 5.0])
    ap.add_argument("--repeat", type=int, default=1, help="closures timed per length (median)")
    ap.add_argument("--effect", type=float, default=0.3,
                    help="position gain of the friction capacity in the synthetic run (0: a clean run)")
    ap.add_argument("--path", choices=("auto", "long"), default="long",
                    help="long (default): every length through the long-run path (windows, then every sample), "
                         "so the growth is that of one method; auto: as capstan close chooses (runs below "
                         "windows.WARM_START_SAMPLES training samples take the slower short path)")
    ap.add_argument("--one", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one is not None:
        print(json.dumps(one_length(args.one, args.repeat, args.effect, args.path == "long")))
        return 0
    rows = []
    for m in args.minutes:
        cmd = [sys.executable, "-m", "capstan.tools.bench.closure", "--one", str(m), "--repeat", str(args.repeat),
               "--effect", str(args.effect), "--path", args.path]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            sys.stderr.write(proc.stderr)
            return proc.returncode
        r = json.loads(proc.stdout.strip().splitlines()[-1])
        med = {k: float(np.median(v)) for k, v in r["stages"].items()}
        r["median_total"] = float(np.median(r["total"]))
        rows.append(r)
        stages = "  ".join(f"{k} {med[k]:.1f}" for k in STAGES)
        stages += " [" + "  ".join(f"{k} {med[k]:.1f}" for k in ("screen", "held-out", "joint", "joint-scored") if k in med) + "]"
        print(f"{m:5.1f} min {r['samples']:9d} samples: closure {r['median_total']:6.1f} s (median of "
              f"{len(r['total'])}; {stages} s)  one simulation {1e3 * r['simulation']:7.1f} ms "
              f"({1e9 * r['simulation'] / r['samples']:5.1f} ns/sample)  peak RSS {r['rss_MB']:7.0f} MB  "
              f"held-out RMSE {r['rmse'][0]:.4f} -> {r['rmse'][1]:.4f} Nm  selected {r['selected']}", flush=True)
    for r in rows:
        print(f"{r['minutes']:g} min: the closure costs {r['median_total'] / r['simulation']:.0f} simulations of the "
              "whole run (a figure the machine's load does not change much)")
    r0 = rows[0]
    for r in rows[1:]:
        print(f"{r['minutes']:g} min vs {r0['minutes']:g} min: samples x{r['samples'] / r0['samples']:.1f}, "
              f"closure x{r['median_total'] / r0['median_total']:.1f}, simulation "
              f"x{r['simulation'] / r0['simulation']:.1f}, peak RSS x{r['rss_MB'] / r0['rss_MB']:.1f}")
    print(f"load average {' '.join(f'{x:.2f}' for x in __import__('os').getloadavg())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
