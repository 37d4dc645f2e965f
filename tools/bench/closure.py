"""Benchmark of the closure's dynamic baseline on every sample: simulation cost per sample
and the whole output-error fit, for runs of growing length at 1 kHz, with time and peak
memory. Prints figures (medians of repeated simulations; fit wall time; ratios against
the shortest run in the same process).

``python -m capstan.tools.bench.closure --minutes 1 5 [60]`` (the 60-minute run, the
issue's 3.6 M samples, takes long on a shared 2-core machine; run it on purpose).

The runs are a testbed plant of the reduced family with a declared environment and
0.02 Nm noise: speed does not depend on where the data come from.
"""

from __future__ import annotations

import argparse
import resource
import time
import tracemalloc
from typing import Sequence

import numpy as np

from capstan.models.closure.dynamic_baseline import DrivingForm, _predict, fit_dynamic
from capstan.models.closure.signals import signals_from_tables
from capstan.models.common.measurement_table import MeasurementTable
from capstan.models.transmission.stick_slip import simulate_unit


def synthetic_run(minutes: float, seed: int = 0) -> MeasurementTable:
    """A testbed run of ``minutes`` at 1 kHz: multisine drive, friction state, noise."""
    t = np.arange(0.0, 60.0 * minutes, 1e-3)
    rng = np.random.default_rng(seed)
    u = sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 6)) / (1 + k) for k, f in enumerate((0.11, 0.23, 0.41, 0.73)))
    u = 6.0 * u / np.max(np.abs(u))
    n = t.size
    x, v, f = np.empty(n), np.empty(n), np.empty(n)
    simulate_unit(t, u, np.array([0, n]), np.zeros(1), np.array([2.0]), np.array([20.0]), 2e5, 1.7, 1.1, 0.03, 0.02,
                  x, v, f, np.empty(0), 0.0)
    tau_out = 20.0 * x + 2.0 * v
    cols = {"t": t, "tau_in": u + 0.02 * rng.standard_normal(n), "tau_out": tau_out + 0.02 * rng.standard_normal(n),
            "q_out": x, "dq_out": v + 1e-3 * rng.standard_normal(n)}
    return MeasurementTable(cols, {"environment": {"k_out": 20.0, "b_out": 2.0}}, f"synthetic {minutes} min")


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, nargs="+", default=[1.0, 5.0])
    ap.add_argument("--repeat", type=int, default=5, help="simulations timed per length (median)")
    args = ap.parse_args(argv)
    rows = []
    for m in args.minutes:
        sig = signals_from_tables([synthetic_run(m)])
        p = np.array([20.0, 2.0, 1.7, 2e5, 1.1, 0.03, 0.02, 0.0])
        _predict(DrivingForm.TESTBED, p, sig, True)
        ts = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            _predict(DrivingForm.TESTBED, p, sig, True)
            ts.append(time.perf_counter() - t0)
        tracemalloc.start()
        t0 = time.perf_counter()
        fit = fit_dynamic(sig)
        t_fit = time.perf_counter() - t0
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        n = len(sig)
        rows.append((m, n, float(np.median(ts)), t_fit, fit.nfev, peak / 1e6))
        print(f"{m:6.1f} min  {n:9d} samples  simulation median {1e3 * np.median(ts):8.1f} ms "
              f"({1e9 * np.median(ts) / n:6.1f} ns/sample)  fit {t_fit:7.1f} s ({fit.nfev} evaluations, "
              f"train RMSE {fit.rmse_Nm:.4f} Nm)  peak traced memory {peak / 1e6:7.1f} MB", flush=True)
    m0 = rows[0]
    for m, n, ts, tf, _, mem in rows[1:]:
        print(f"{m:g} min vs {m0[0]:g} min: samples x{n / m0[1]:.1f}, simulation x{ts / m0[2]:.1f}, "
              f"fit x{tf / m0[3]:.1f}, memory x{mem / max(m0[5], 1e-9):.1f}")
    print(f"max RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3:.0f} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
