"""Mutation check of the fast test selection: does ``pytest -m "not slow"`` see a careless edit?

    .venv/bin/python -m capstan.tools.bench.mutation_check [--only ID ...] [--list] [--jobs 1]

Each entry of :data:`MUTATIONS` is one small change to core behaviour (a limit, a filter
coefficient, a count, a validation check, a selection rule, a protocol constant). The script
copies the repository (without ``.venv``) to a scratch directory, applies one mutation at a
time there (the worktree is never touched), and runs only the fast tests that import the
mutated module or a package module that imports it directly (``--narrow``: only the first)::

    pytest -m "not slow" -x -q -p no:cacheprovider <those test files>

with the copy first on ``PYTHONPATH`` (a ``capstan`` namespace of links to the copy's
folders) and a fresh, empty ``NUMBA_CACHE_DIR`` per mutation of a module with Numba code:
Numba's cache does not follow a change of a module that a cached function calls, so a shared
cache could hide a mutation (or keep one after it is undone). Mutations of plain Python modules
share one cache. A mutation is *killed* when pytest fails, *survived* when
the selection passes. The unmutated copy is run first on the union of the selections (a
failing baseline would make every mutation look killed).

Prints one line per mutation and a summary; exit status 1 if any mutation survived. It
runs one pytest at a time (the machine is shared): 15-25 mutations take 15-40 min.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("controller", "drivers", "models", "tools", "config")
#: test files that check the package's layout, not its behaviour (they lint the installed tree)
NOT_BEHAVIOUR = frozenset({"test_import_contracts.py", "test_packaging.py"})


@dataclass(frozen=True)
class Mutation:
    """One edit: ``old`` (must occur exactly once in ``path``) replaced by ``new``."""

    id: str
    path: str
    old: str
    new: str
    what: str
    #: test files to run besides the importers (a module reached only through another one)
    also: tuple[str, ...] = ()


MUTATIONS: tuple[Mutation, ...] = (
    # ---- controller: the safety stage, the law, its configuration
    Mutation("safety-torque-fault", "controller/law/safety.py",
             "if abs(tau_raw_Nm) > tau_fault_Nm:", "if abs(tau_raw_Nm) > 1.5 * tau_fault_Nm:",
             "hard torque fault limit loosened by 1.5x"),
    Mutation("safety-stale-imu", "controller/law/safety.py",
             "if not (r.t_s - r.imu_t_s <= imu_timeout_s):", "if not (r.t_s - r.imu_t_s <= 2.0 * imu_timeout_s):",
             "IMU staleness timeout doubled"),
    Mutation("safety-rate-clamp", "controller/law/safety.py",
             "rate_lo, rate_hi = tau_prev_cmd_Nm - dtau_max_step_Nm, tau_prev_cmd_Nm + dtau_max_step_Nm",
             "rate_lo, rate_hi = tau_prev_cmd_Nm - 2.0 * dtau_max_step_Nm, tau_prev_cmd_Nm + 2.0 * dtau_max_step_Nm",
             "command rate clamp doubled"),
    Mutation("safety-quantum-round", "controller/law/safety.py",
             "g = math.floor(tau / q + 0.5) * q", "g = math.floor(tau / q) * q",
             "command quantisation truncates instead of rounding"),
    Mutation("rest-gate-edge", "controller/law/feedforward.py",
             "lo = 0.8 * band_rad_s", "lo = 0.5 * band_rad_s",
             "rest gate's lower edge 0.8 -> 0.5 of the band"),
    Mutation("rest-gate-debounce", "controller/law/step.py",
             "gate = g_now if st[S_FF_OUT] != 0.0 else 0.0", "gate = g_now",
             "rest gate opens on the first sample (debounce dropped)", ("tests/test_torque_loop.py",)),
    Mutation("integrator-clamp", "controller/law/step.py",
             "st[S_INT] = min(max(st[S_INT] + cfg[C_KI_DT] * e, -lim), lim)", "st[S_INT] = st[S_INT] + cfg[C_KI_DT] * e",
             "integrator anti-windup clamp dropped", ("tests/test_torque_loop.py", "tests/test_integral_limit.py")),
    Mutation("lowpass-pole", "controller/law/ldo.py",
             "return math.exp(-2.0 * math.pi * cutoff_hz * dt_s)", "return math.exp(-math.pi * cutoff_hz * dt_s)",
             "first-order low-pass pole: cutoff halved (filter coefficient)"),
    Mutation("config-fault-vs-clamp", "controller/law/safety_config.py",
             "if s.tau_fault_Nm < s.tau_max_Nm:", "if s.tau_fault_Nm < 0.5 * s.tau_max_Nm:",
             "validation: a fault limit below the clamp accepted", ("tests/test_safety.py",)),
    Mutation("runtime-fresh-vs-period", "controller/runtime/config.py",
             "if out.sensor_fresh_s < period", "if out.sensor_fresh_s < 0.5 * period",
             "validation: sensor_fresh_s below the period accepted"),
    # ---- drivers: byte protocols, CiA 402
    Mutation("loadcell-length", "drivers/serial/loadcell_protocol.py",
             "if len(frame) != FRAME_LEN or", "if len(frame) < FRAME_LEN or",
             "load-cell frame length check accepts longer frames"),
    Mutation("loadcell-checksum", "drivers/serial/loadcell_protocol.py",
             "return sum(values_bytes) & 0xFF", "return (sum(values_bytes) + 1) & 0xFF",
             "load-cell checksum rule off by one"),
    Mutation("loadcell-tare-sign", "drivers/serial/loadcell.py",
             "return (s[0] * raw_mV_V[0] + o[0] - t[0],", "return (s[0] * raw_mV_V[0] + o[0] + t[0],",
             "tare added instead of subtracted on the first channel"),
    Mutation("xbus-checksum", "drivers/serial/xbus.py",
             "return (-sum(body)) & 0xFF", "return (-sum(body) - 1) & 0xFF",
             "Xbus checksum rule off by one"),
    Mutation("ds402-enable-word", "drivers/canopen/cia402.py",
             "Command402.ENABLE_OPERATION: 0x000F,", "Command402.ENABLE_OPERATION: 0x0007,",
             "DS402 enable-operation controlword = switch-on's"),
    Mutation("ds402-transition-4", "drivers/canopen/cia402.py",
             "Transition(4, _S.SWITCHED_ON, _S.OPERATION_ENABLED, _C.ENABLE_OPERATION, 1.0),",
             "Transition(4, _S.SWITCHED_ON, _S.OPERATION_ENABLED, _C.SWITCH_ON, 1.0),",
             "DS402 transition 4 triggered by the wrong command"),
    Mutation("heartbeat-periods", "drivers/canopen/motor.py",
             "HEARTBEAT_LOSS_PERIODS = 3 ", "HEARTBEAT_LOSS_PERIODS = 30 ",
             "drive heartbeat loss after 30 periods instead of 3"),
    # ---- models: physics and the closure's selection
    Mutation("pretension-branch", "models/transmission/pretension.py",
             "branch_b = T_b_N * math.exp(-mu * (theta - c_star))", "branch_b = T_b_N * math.exp(-mu * (theta + c_star))",
             "pretension field: sign error in the far branch"),
    Mutation("pretension-profile", "models/distributed/params.py",
             "tens = pretension_N * np.maximum(", "tens = pretension_N * np.minimum(",
             "distributed pretension profile: the weaker of the two ends", ("tests/test_distributed_physics.py",)),
    Mutation("lugre-stribeck", "models/transmission/lugre.py",
             "return F_c + (F_s - F_c) * math.exp(-x * x)", "return F_c + (F_s - F_c) * math.exp(-x)",
             "LuGre Stribeck curve exponent 2 -> 1"),
    Mutation("closure-material", "models/closure/scoring.py",
             "MATERIAL = 0.05", "MATERIAL = 0.0",
             "closure selection threshold (5 % held-out RMSE) dropped"),
    Mutation("closure-prefer-catalogue", "models/closure/scoring.py",
             "PREFER_CATALOGUE = 0.7", "PREFER_CATALOGUE = 1.5",
             "closure's catalogue-first rule reversed"),
)


def _module_of(rel: str) -> str:
    """``controller/law/safety.py`` -> ``capstan.controller.law.safety``."""
    return "capstan." + rel[:-3].replace("/", ".")


def _importers(repo: Path, module: str) -> set[str]:
    """Package modules that import ``module`` directly (``from capstan.x import y``, ``import capstan.x.y``,
    ``from capstan.x.y import ...``)."""
    pkg, _, leaf = module.rpartition(".")
    pat = re.compile(rf"(?:from\s+{re.escape(module)}\s+import|import\s+{re.escape(module)}\b|"
                     rf"from\s+{re.escape(pkg)}\s+import\s+[^\n]*\b{re.escape(leaf)}\b)")
    out = set()
    for top in PACKAGES[:-1]:
        for f in (repo / top).rglob("*.py"):
            if pat.search(f.read_text(errors="replace")):
                out.add(_module_of(str(f.relative_to(repo))))
    return out - {module}


def test_files(repo: Path, rel: str, wide: bool = False) -> list[str]:
    """Test files that import the mutated module (``wide``: or a package module that imports it directly)."""
    mods = {_module_of(rel)} | (_importers(repo, _module_of(rel)) if wide else set())
    pats = []
    for m in mods:
        pkg, _, leaf = m.rpartition(".")
        pats.append(re.compile(rf"(?:{re.escape(m)}\b|from\s+{re.escape(pkg)}\s+import\s+[^\n]*\b{re.escape(leaf)}\b)"))
    files = []
    for f in sorted((repo / "tests").glob("test_*.py")):
        if f.name in NOT_BEHAVIOUR:
            continue
        text = f.read_text(errors="replace")
        if any(p.search(text) for p in pats):
            files.append(str(f.relative_to(repo)))
    return files


def _copy(dst: Path) -> None:
    """The repository's tracked and untracked working files (not .venv, caches, runs) under ``dst``, and a
    ``capstan`` namespace of links to its folders under ``dst/.mutpkg``."""
    ignore = shutil.ignore_patterns(".venv", ".git", ".numba_cache", "runs", "__pycache__", "*.egg-info")
    shutil.copytree(REPO, dst, ignore=ignore, symlinks=True)
    ns = dst / ".mutpkg" / "capstan"
    ns.mkdir(parents=True)
    for top in PACKAGES:
        (ns / top).symlink_to(dst / top)


def _pytest(copy: Path, files: list[str], cache: Path, timeout_s: float) -> tuple[str, float, str, list[str]]:
    env = {**os.environ, "PYTHONPATH": str(copy / ".mutpkg"), "NUMBA_CACHE_DIR": str(cache),
           "MPLBACKEND": "Agg"}
    t0 = time.monotonic()
    try:
        res = subprocess.run([sys.executable, "-m", "pytest", "-m", "not slow", "-x", "-q", "-p", "no:cacheprovider",
                              *files], cwd=copy, env=env, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return "timeout", time.monotonic() - t0, "", []
    lines = res.stdout.strip().splitlines() or [""]
    failed = [ln.split(" - ")[0].split(" ", 1)[1] for ln in lines if ln.startswith(("FAILED tests/", "ERROR tests/"))]
    tail = "; ".join([lines[-1], *failed[:2]])
    return ("survived" if res.returncode == 0 else "killed"), time.monotonic() - t0, tail, failed


def _cache(tmp: Path, i: int, source: str) -> Path:
    """A fresh Numba cache for a mutation of a compiled module; a shared one (compiled from unmutated
    code) for a module without Numba code, which no cached compiled function can have inlined."""
    return tmp / (f"cache-{i}" if "numba" in source else "cache-shared")


def _check_target(copy: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(copy / ".mutpkg")}
    where = subprocess.run([sys.executable, "-c", "import capstan.controller as c; print(c.__file__)"],
                           env=env, capture_output=True, text=True, check=True).stdout.strip()
    if not where.startswith(str(copy)):
        raise SystemExit(f"the copy is not the one imported: capstan.controller from {where}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="*", help="mutation ids to run (default: all)")
    ap.add_argument("--list", action="store_true", help="list the mutations and their test files, run nothing")
    ap.add_argument("--no-baseline", action="store_true", help="skip the unmutated run")
    ap.add_argument("--narrow", action="store_true",
                    help="only the tests that import the mutated module (default: also those of its direct importers)")
    ap.add_argument("--timeout", type=float, default=900.0, help="per pytest run [s]")
    ap.add_argument("--files", nargs="*", help="run exactly these test files for every chosen mutation")
    ap.add_argument("--tests-at", metavar="REV", help="take tests/ from this git revision (e.g. main: the suite before a change)")
    args = ap.parse_args(argv)
    chosen = [m for m in MUTATIONS if not args.only or m.id in args.only]
    for m in chosen:
        text = (REPO / m.path).read_text()
        if text.count(m.old) != 1:
            print(f"{m.id:26s} NOT APPLICABLE: {m.path} has the text {text.count(m.old)} times (the code moved)")
    chosen = [m for m in chosen if (REPO / m.path).read_text().count(m.old) == 1]
    if args.list:
        for m in chosen:
            files = sorted(set(test_files(REPO, m.path, not args.narrow)) | set(m.also))
            print(f"{m.id:26s} {m.path}: {m.what}\n{'':27s}{' '.join(files) or '(none)'}")
        return 0
    with tempfile.TemporaryDirectory(prefix="capstan-mut-") as tmp:
        copy = Path(tmp) / "repo"
        _copy(copy)
        if args.tests_at:
            shutil.rmtree(copy / "tests")
            tar = subprocess.run(["git", "-C", str(REPO), "archive", args.tests_at, "tests"], check=True, capture_output=True)
            subprocess.run(["tar", "-x", "-C", str(copy)], input=tar.stdout, check=True)
        _check_target(copy)
        if not args.no_baseline:
            union = sorted({f for m in chosen for f in test_files(copy, m.path, not args.narrow)})
            status, wall, tail, failed = _pytest(copy, union, Path(tmp) / "cache-base", args.timeout)
            if status == "killed" and failed:       # a test that fails on a loaded host: rerun it once alone
                again = _pytest(copy, failed, Path(tmp) / "cache-base", args.timeout)
                status = "survived" if again[0] == "survived" else status
                tail += f" (rerun alone: {'passed, FLAKY' if again[0] == 'survived' else 'failed again'})"
            print(f"{'baseline (unmutated)':26s} {'ok' if status == 'survived' else status.upper():8s} {wall:6.0f} s  {tail}",
                  flush=True)
            if status != "survived":
                return 2
        survivors = []
        for i, m in enumerate(chosen):
            path = copy / m.path
            orig = path.read_text()
            files = args.files or sorted(set(test_files(copy, m.path, not args.narrow)) | {f for f in m.also if (copy / f).exists()})
            path.write_text(orig.replace(m.old, m.new))
            try:
                if not files:
                    status, wall, tail, failed = "survived", 0.0, "no test file imports it", []
                else:
                    status, wall, tail, failed = _pytest(copy, files, _cache(Path(tmp), i, orig), args.timeout)
            finally:
                path.write_text(orig)
            if status == "killed" and failed:       # the failing test must pass unmutated, else it is a flake
                ok = _pytest(copy, failed[:1], _cache(Path(tmp), -1 - i, orig), args.timeout)[0] == "survived"
                if not ok:
                    status, tail = "flaky", tail + " (fails unmutated too)"
            if status != "killed":
                survivors.append(m.id)
            print(f"{m.id:26s} {status.upper():8s} {wall:6.0f} s  {len(files):2d} files  {m.what}  [{tail}]", flush=True)
        print(f"\n{len(chosen) - len(survivors)} of {len(chosen)} killed; survivors: {', '.join(survivors) or 'none'}")
        return 1 if survivors else 0


if __name__ == "__main__":
    sys.exit(main())
