"""Benchmark of the composed control step (LDO + friction feedforward + gravity + safety).

    .venv/bin/python -m capstan.tools.bench.step [--calls 1000000] [--loop ldo|pid]

Prints two figures:

* **single call from Python**: ``perf_counter_ns`` around each ``Controller.step()`` in a
  tight loop (what the daemon's loop pays per cycle, including the Numba dispatch and
  record unboxing), median / p99 / p99.9 / max over ``--calls`` calls;
* **batched**: the njit step called ``--calls`` times from compiled code, total / calls
  (the pure compute cost of the step).

Target: single-call p99 <= 5 us. Run on an otherwise idle machine; the figures include
hypervisor noise (see design.md §4).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from numba import njit

from capstan.controller.law.config import ControllerConfig
from capstan.controller.law.core import Controller
from capstan.controller.law.step import control_step


@njit(cache=True)
def _batch(cfg: np.ndarray, st: np.ndarray, rec: np.ndarray, n: int) -> float:
    """Run the step ``n`` times on slowly varying healthy measurements; returns a checksum."""
    acc = 0.0
    r = rec[0]
    for k in range(n):
        t = 1.0 + k * 1e-3
        r.t_s = t
        r.lc_t_s = t
        r.imu_t_s = t
        r.motor_t_s = t
        r.imu_new = 1 if k % 5 < 2 else 0
        r.dq_out_rad_s = 0.3 * np.sin(1e-3 * k)
        acc += control_step(cfg, st, rec)
    return acc


def _healthy(ctl: Controller) -> None:
    rec = ctl.record[0]
    for name in ("T_up_in_N", "T_up_out_N", "T_lo_out_N", "T_lo_in_N"):
        rec[name] = 150.0
    rec["q_out_rad"] = 0.3


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the figures; returns 0."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--calls", type=int, default=1_000_000)
    ap.add_argument("--loop", choices=("ldo", "pid"), default="ldo")
    args = ap.parse_args(argv)
    ctl = Controller(ControllerConfig.from_mapping({"torque_loop": args.loop}))
    ctl.warmup()
    _healthy(ctl)
    n = args.calls
    rec = ctl.record[0]
    samples = np.empty(n, dtype=np.int64)
    step = ctl.step
    clock = time.perf_counter_ns
    for k in range(n):
        t = 1.0 + k * 1e-3
        rec["t_s"] = t
        rec["lc_t_s"] = t
        rec["imu_t_s"] = t
        rec["motor_t_s"] = t
        rec["imu_new"] = 1 if k % 5 < 2 else 0
        t0 = clock()
        step()
        samples[k] = clock() - t0
    if ctl.faulted:
        print(f"warning: controller faulted during the benchmark: {ctl.fault_bits!r}")
    us = samples / 1000.0
    print(f"control step ({args.loop} + feedforward + gravity + safety), {n} calls")
    print(f"  single call from Python: median {np.median(us):.2f} us, p99 {np.percentile(us, 99):.2f} us, "
          f"p99.9 {np.percentile(us, 99.9):.2f} us, max {us.max():.1f} us   (target p99 <= 5 us)")

    ctl.reset()
    _healthy(ctl)
    _batch(ctl.cfg_array, ctl.state, ctl.record, 10)
    ctl.reset()
    t0 = time.perf_counter_ns()
    _batch(ctl.cfg_array, ctl.state, ctl.record, n)
    dt = (time.perf_counter_ns() - t0) / n / 1000.0
    print(f"  batched in compiled code: {dt * 1000:.0f} ns per step")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
