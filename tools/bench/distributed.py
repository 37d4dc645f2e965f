"""Speed benchmark of the distributed model (run on demand, prints figures; not a test).

    .venv/bin/python -m capstan.tools.bench.distributed [--quick] [--nodes 10 50] [--repeats 3]
        [--duration 60] [--window 3] [--scenario config/scenarios/testbed_multisine.yaml]

The scenario (default: the shipped testbed multisine, run for ``--duration`` s, testbed
output, its sample rate) is simulated with N = 10 and N = 50 in the model's modes:

* ``step()``: one call per 1 ms control period with the input held (what the simulated
  rig does), compared against a held-input reference (``step_adaptive``, rtol 1e-8);
* ``simulate()`` fixed: one step per sample interval;
* ``simulate()`` adaptive at the default tolerances (rtol 1e-6, atol 1e-9), and at the
  loosest tolerance of a ladder that keeps ``max |delta tau_out| <= 0.01 Nm`` over the run.

Figures are simulated seconds per wall second (and per CPU second of this process),
median of ``--repeats`` runs. Each mode's first call, which compiles the Numba code or
loads it from the cache, is timed separately and excluded. Accuracy is ``max |delta
tau_out|`` at the samples against a reference run of the same model at rtol 1e-9,
atol 1e-12; that reference is checked against scipy Radau at rtol 1e-10 on a short window.

Radau comparison: ``scipy.integrate.solve_ivp(method="Radau")`` integrates the *same*
equations (:mod:`capstan.models.distributed.ode`: the model's compiled right-hand side and its
analytic Jacobian, dense for N <= 20, sparse otherwise) over the first ``--window``
seconds (Radau on the whole run at N = 50 takes many minutes). Radau runs once per
tolerance of a ladder; the fastest run meeting the same 0.01 Nm bound is "matched".
The ratio compares simulated seconds per wall second on that same window: for the
matched adaptive mode, for the fixed mode, and for the fastest of the two whose
``max |delta tau_out|`` on the window is within the same 0.01 Nm (named in the row).

Targets (issue 2): N = 10 >= 200x real time, N = 50 >= 20x real time, >= 100x faster
than Radau. Timings include whatever else runs on the machine (load average printed).
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import statistics
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import numba
import scipy
from scipy.integrate import solve_ivp

from capstan.models.common.config_tools import load_yaml
from capstan.models.distributed.model import DistributedModel
from capstan.models.distributed.ode import ode_problem
from capstan.tools.offline.scenario import Scenario
from capstan.tools.offline.shipped import config_path

DEFAULT_SCENARIO = config_path("scenarios/testbed_multisine.yaml")
BOUND_NM = 0.01
RATE_TARGETS = {10: 200.0, 50: 20.0}
RADAU_TARGET = 100.0
REF_RTOL, REF_ATOL = 1e-9, 1e-12
ZOH_REF_RTOL, ZOH_REF_ATOL = 1e-8, 1e-11
#: tolerance ladders, 1-2-5 steps for both solvers (a decade ladder lands each solver up
#: to 10x tighter than it needs for the bound, whichever it happens to penalise)
OUR_LADDER = (1e-3, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5, 1e-5, 1e-6)
RADAU_LADDER = (1e-4, 5e-5, 2e-5, 1e-5, 5e-6, 2e-6, 1e-6, 1e-7)
ATOL_PER_RTOL = 1e-3      # atol [m, rad] = 1e-3 rtol, as the model's defaults


class _OverBudget(Exception):
    """Raised inside the Radau right-hand side when a run exceeds its time budget."""


@dataclass
class Timing:
    """Median wall and CPU seconds of repeated runs, and the last run's output torque."""

    wall_s: float
    cpu_s: float
    tau_out_Nm: np.ndarray


def machine() -> str:
    """One line of host facts."""
    cpu = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (f"{platform.system()} {platform.release()} {platform.machine()}, CPU '{cpu}', "
            f"{os.cpu_count()} CPUs; Python {platform.python_version()}, numpy {np.__version__}, "
            f"numba {numba.__version__}, scipy {scipy.__version__}")


def load() -> str:
    """The 1/5/15-minute load averages."""
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def scenario_inputs(path: Path, n_nodes: int, duration_s: float) -> tuple[Scenario, np.ndarray, np.ndarray]:
    """The scenario at ``n_nodes`` and ``duration_s``, its sample times [s] and input torque [Nm]."""
    cfg = dict(load_yaml(path))
    cfg["duration_s"] = duration_s
    cfg["transmission"] = dict(cfg.get("transmission") or {}, n_nodes=n_nodes)
    sc = Scenario.from_mapping(cfg, path.parent)
    ns = int(round(sc.duration_s * sc.sample_rate_hz)) + 1
    t = np.arange(ns) / sc.sample_rate_hz
    return sc, t, sc.excitation.torque_Nm(t)


def timed(run: Callable[[], np.ndarray], repeats: int) -> Timing:
    """Median wall/CPU time of ``repeats`` calls of ``run`` (which returns tau_out)."""
    walls, cpus = [], []
    tau = np.zeros(0)
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        tau = run()
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    return Timing(statistics.median(walls), statistics.median(cpus), tau)


def step_run(model: DistributedModel, t: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``step()`` once per sample interval with the input held; tau_out at the samples.

    The intervals and inputs are converted to Python floats beforehand (a controller passes
    floats), so the loop times ``step()`` and the ``tau_out_Nm`` read, not numpy indexing.
    """
    model.reset()
    tau = np.empty(t.shape[0])
    tau[0] = model.tau_out_Nm
    step = model.step
    for k, (dt, uk) in enumerate(zip(np.diff(t).tolist(), u[:-1].tolist()), start=1):
        step(dt, uk)
        tau[k] = model.tau_out_Nm
    return tau


def sim_run(model: DistributedModel, t: np.ndarray, u: np.ndarray, **kw: Any) -> np.ndarray:
    """``simulate()`` from the initial state; tau_out at the samples."""
    model.reset()
    return model.simulate(t, u, **kw).tau_out_Nm


def radau_run(model: DistributedModel, t: np.ndarray, u: np.ndarray, rtol: float, atol: float,
              budget_s: float) -> tuple[float, np.ndarray | None, str]:
    """Radau on the model's equations from the initial state: (wall s, tau_out or None, note)."""
    model.reset()
    prob = ode_problem(model, t, u, sparse_jac=model.n > 20)
    prob.fun(t[0], prob.y0)                     # compile the right-hand side outside the timing
    prob.jac(t[0], prob.y0)
    start = time.perf_counter()

    def fun(tt: float, y: np.ndarray) -> np.ndarray:
        if prob.n_fun % 200 == 0 and time.perf_counter() - start > budget_s:
            raise _OverBudget
        return prob.fun(tt, y)

    try:
        sol = solve_ivp(fun, (t[0], t[-1]), prob.y0, method="Radau", t_eval=t, rtol=rtol, atol=atol,
                        jac=prob.jac)
    except _OverBudget:
        return time.perf_counter() - start, None, f"stopped after {budget_s:.0f} s"
    wall = time.perf_counter() - start
    if not sol.success:
        return wall, None, f"failed: {sol.message}"
    return wall, prob.tau_out_Nm(sol.y, u), f"{sol.nfev} f, {sol.njev} J, {sol.nlu} LU"


def fastest_within_bound(modes: dict[str, tuple[float, float]]) -> tuple[str, float] | None:
    """The fastest of ``modes`` (name -> (sim-s/wall-s, max |delta tau_out| [Nm])) whose error
    is within ``BOUND_NM``, as (name, rate); None if none is."""
    ok = [(rate, name) for name, (rate, err) in modes.items() if err <= BOUND_NM]
    if not ok:
        return None
    rate, name = max(ok)
    return name, rate


def fmt_rate(x: float) -> str:
    return f"{x:8.1f}" if x < 1e4 else f"{x:8.0f}"


def bench_nodes(path: Path, n: int, args: argparse.Namespace) -> list[str]:
    """All figures for one N; returns the table rows (also printed as they come)."""
    sc, t, u = scenario_inputs(path, n, args.duration)
    dur = float(t[-1] - t[0])
    model = DistributedModel(sc.plant.transmission, sc.plant.boundary)
    rows: list[str] = []

    def emit(line: str) -> None:
        print(line, flush=True)
        rows.append(line)

    w0 = time.perf_counter()
    step_run(model, t[:4], u[:4])
    sim_run(model, t[:4], u[:4], adaptive=False)
    sim_run(model, t[:4], u[:4], adaptive=True)
    first = time.perf_counter() - w0
    w0 = time.perf_counter()
    ref = sim_run(model, t, u, adaptive=True, rtol=REF_RTOL, atol=REF_ATOL)
    ref_wall = time.perf_counter() - w0
    model.reset()
    model.step_adaptive, model.rtol, model.atol = True, ZOH_REF_RTOL, ZOH_REF_ATOL
    ref_zoh = step_run(model, t, u)
    model.step_adaptive, model.rtol, model.atol = False, 1e-6, 1e-9
    print(f"N = {n}: first calls (Numba compile or cache load) {first:.1f} s, excluded; "
          f"reference run {ref_wall:.1f} s", flush=True)

    target = RATE_TARGETS.get(n)

    def row(mode: str, settings: str, tm: Timing, reference: np.ndarray) -> float:
        err = float(np.max(np.abs(tm.tau_out_Nm - reference)))
        rate = dur / tm.wall_s
        met = "(no target)" if target is None else f">= {target:.0f}x " + ("met" if rate >= target else "NOT met")
        acc = "ok" if err <= BOUND_NM else "> 0.01"
        emit(f"{n:3d}  {mode:24s} {settings:30s} {fmt_rate(rate)} {fmt_rate(dur / tm.cpu_s)}  "
             f"{err:9.2e} {acc:6s}  {met}")
        return rate

    row("step() 1 ms held input", "Newton rtol 1e-6 atol 1e-9", timed(lambda: step_run(model, t, u), args.repeats),
        ref_zoh)
    row("simulate() fixed 1 step", "Newton rtol 1e-6 atol 1e-9",
        timed(lambda: sim_run(model, t, u, adaptive=False), args.repeats), ref)
    row("simulate() adaptive", "rtol 1e-6 atol 1e-9 (default)",
        timed(lambda: sim_run(model, t, u, adaptive=True), args.repeats), ref)
    matched = None
    for rtol in OUR_LADDER:
        tau = sim_run(model, t, u, adaptive=True, rtol=rtol, atol=rtol * ATOL_PER_RTOL)
        if np.max(np.abs(tau - ref)) <= BOUND_NM:
            matched = rtol
            break
    if matched is None:
        emit(f"{n:3d}  no adaptive tolerance in {OUR_LADDER} meets {BOUND_NM} Nm")
        return rows
    row("simulate() adaptive", f"rtol {matched:.0e} atol {matched * ATOL_PER_RTOL:.0e} (matched)",
        timed(lambda: sim_run(model, t, u, adaptive=True, rtol=matched, atol=matched * ATOL_PER_RTOL),
              args.repeats), ref)

    # --- Radau on the window
    kw = int(round(args.window * sc.sample_rate_hz)) + 1
    tw, uw, refw = t[:kw], u[:kw], ref[:kw]
    win = float(tw[-1] - tw[0])
    ours = timed(lambda: sim_run(model, tw, uw, adaptive=True, rtol=matched, atol=matched * ATOL_PER_RTOL),
                 args.repeats)
    ours_fixed = timed(lambda: sim_run(model, tw, uw, adaptive=False), args.repeats)
    our_rate, fixed_rate = win / ours.wall_s, win / ours_fixed.wall_s
    our_err = float(np.max(np.abs(ours.tau_out_Nm - refw)))
    fixed_err = float(np.max(np.abs(ours_fixed.tau_out_Nm - refw)))
    print(f"     window 0-{win:g} s: ours adaptive rtol {matched:.0e} {our_rate:.1f} sim-s/wall-s "
          f"(max|dtau| {our_err:.1e} Nm), fixed {fixed_rate:.1f} (max|dtau| {fixed_err:.1e} Nm)",
          flush=True)
    fastest = fastest_within_bound({f"adaptive rtol {matched:.0e}": (our_rate, our_err),
                                    "fixed 1 step": (fixed_rate, fixed_err)})
    best: tuple[float, float] | None = None
    for rtol in (args.radau_ladder or RADAU_LADDER):
        wall, tau, note = radau_run(model, tw, uw, rtol, rtol * ATOL_PER_RTOL, args.radau_budget)
        err = float(np.max(np.abs(tau - refw))) if tau is not None else float("nan")
        ok = tau is not None and err <= BOUND_NM
        print(f"     Radau rtol {rtol:.0e}: {win / wall:8.3f} sim-s/wall-s, max|dtau| {err:.1e} Nm, {note}",
              flush=True)
        if ok and (best is None or wall < best[1]):
            best = (rtol, wall)
    if best is None:
        emit(f"{n:3d}  Radau: no tolerance met {BOUND_NM} Nm within the budget")
    else:
        r_rate = win / best[1]
        ratio = our_rate / r_rate
        emit(f"{n:3d}  Radau rtol {best[0]:.0e} (matched) {r_rate:10.3f} sim-s/wall-s on 0-{win:g} s; "
             f"ours adaptive {ratio:7.0f}x faster, fixed {fixed_rate / r_rate:7.0f}x  "
             f">= {RADAU_TARGET:.0f}x {'met' if ratio >= RADAU_TARGET else 'NOT met'}")
        if fastest is None:
            emit(f"{n:3d}  Radau ratio: none of our modes meets {BOUND_NM} Nm on 0-{win:g} s")
        else:
            mode, rate = fastest
            emit(f"{n:3d}  Radau ratio of our fastest mode within {BOUND_NM} Nm on 0-{win:g} s "
                 f"({mode}): {rate / r_rate:7.0f}x faster  >= {RADAU_TARGET:.0f}x "
                 f"{'met' if rate / r_rate >= RADAU_TARGET else 'NOT met'}")
    # --- reference check against Radau at tight tolerance
    kc = int(round(args.check_window * sc.sample_rate_hz)) + 1
    wall, tau, note = radau_run(model, t[:kc], u[:kc], 1e-10, 1e-13, args.radau_budget * 4)
    if tau is None:
        emit(f"{n:3d}  reference check: Radau rtol 1e-10 {note}")
    else:
        emit(f"{n:3d}  reference (ours rtol 1e-9) vs Radau rtol 1e-10 on 0-{t[kc - 1]:g} s: "
             f"max|dtau_out| {np.max(np.abs(tau - ref[:kc])):.1e} Nm (tau_out range {np.ptp(tau):.2f} Nm, "
             f"Radau {wall:.0f} s)")
    return rows


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the table; returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", type=Path, default=DEFAULT_SCENARIO)
    ap.add_argument("--nodes", type=int, nargs="+", default=[10, 50])
    ap.add_argument("--duration", type=float, default=60.0, help="simulated time [s]")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--window", type=float, default=3.0, help="Radau comparison window [s]")
    ap.add_argument("--check-window", type=float, default=1.0, help="reference check window [s]")
    ap.add_argument("--radau-budget", type=float, default=300.0, help="wall-time limit per Radau run [s]")
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: 4 s, Radau window 1 s (rtol 1e-6 only), check window 0.5 s, one repeat")
    args = ap.parse_args(argv)
    args.radau_ladder = None
    if args.quick:
        args.duration, args.window, args.check_window = 4.0, 1.0, 0.5
        args.repeats, args.radau_budget = 1, 30.0
        args.radau_ladder = (1e-6,)
    start = datetime.datetime.now().astimezone()
    print(f"distributed-model benchmark, {start:%Y-%m-%d %H:%M %Z}{' (quick)' if args.quick else ''}")
    print(machine())
    print(f"scenario {args.scenario.name}, {args.duration:g} s; load average at start {load()}")
    print("  N  mode                     settings                       sim-s/wall-s  /CPU-s  "
          "max|dtau_out| Nm  target")
    rows: list[str] = []
    for n in args.nodes:
        rows += bench_nodes(args.scenario, n, args)
    print(f"\nsummary ({datetime.datetime.now().astimezone():%Y-%m-%d %H:%M %Z}, load average at end {load()}):")
    for line in rows:
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
