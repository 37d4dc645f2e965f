"""``capstan replay LOG.mcap [--config OVERRIDE.yaml] [--json]``: re-run the controller on
the logged measurements.

With the logged config the replayed commands must equal the logged ones bit for bit;
the command reports max |dtau_m| (0 expected) and exits 1 otherwise. With an override
(a YAML mapping merged key by key over the logged config) it writes a what-if log and
a plot. The replay is open loop: the plant does not react to the what-if commands, the
logged measurements are fed unchanged.

Only the fields the loop writes before the step (``cycle`` and
``controller.records.MEASUREMENT_FIELDS``) are copied from the log into the controller's
record; everything the step computes is recomputed from a fresh controller.
"""

from __future__ import annotations

import argparse
import copy
import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import yaml

from models.config_tools import load_yaml
from models.errors import ConfigError, DataFormatError

HELP = "re-run the controller on a logged MCAP file (bit-exact check, or what-if with --config)"
_log = logging.getLogger(__name__)

#: progress bar when the log is longer than this [cycles]
PROGRESS_MIN_CYCLES = 300_000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``capstan replay``."""
    parser.add_argument("log", nargs="+", help="capstan MCAP log (several = one rotated run, in order)")
    parser.add_argument("--config", help="override YAML merged over the logged config (what-if)")
    parser.add_argument("--out", help="what-if log path (default: LOG_whatif.mcap next to the log)")
    parser.add_argument("--no-plot", action="store_true", help="do not write the what-if plot")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


@dataclass
class ReplayResult:
    """Outcome of one replay.

    :ivar replayed: records with the step outputs recomputed.
    :ivar max_abs_dtau_m_Nm: max |replayed - logged| of ``tau_m_cmd_Nm`` (inf if a NaN
        appears on one side only).
    :ivar n_different: cycles whose command differs in any bit.
    :ivar first_different: index of the first such cycle, -1 if none.
    :ivar wall_s: time spent stepping [s].
    """

    replayed: np.ndarray
    max_abs_dtau_m_Nm: float
    n_different: int
    first_different: int
    wall_s: float


#: a NaN payload no controller computes; detects whether the step wrote in place
_SENTINEL = np.array([0x7FF4DEADBEEF0001], dtype=np.uint64).view(np.float64)[0]


class _NoInPlace(Exception):
    """The controller did not write its outputs into a swapped-in record."""


def merge_config(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """Deep merge: mappings merge key by key, any other value in ``override`` replaces."""
    out = copy.deepcopy(dict(base))
    for k, v in override.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = merge_config(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def build_controller(cfg: Mapping[str, Any]) -> Any:
    """A fresh, warmed-up :class:`controller.core.Controller` from a daemon config mapping.

    :raises ConfigError: if the ``controller`` section is missing or invalid.
    """
    from controller.config import ControllerConfig
    from controller.core import Controller
    section = cfg.get("controller")
    if not isinstance(section, Mapping):
        raise ConfigError("controller", "missing from the config (the log stores none?)")
    ctl = Controller(ControllerConfig.from_mapping(section))
    ctl.warmup()
    return ctl


def replay_records(records: np.ndarray, ctl: Any, input_fields: tuple[str, ...],
                   output_fields: tuple[str, ...], command_field: str = "tau_m_cmd_Nm",
                   progress: Callable[[int, int], None] | None = None) -> ReplayResult:
    """Step ``ctl`` once per logged record on the logged inputs.

    :param ctl: object with ``record`` (shape (1,) structured array) and ``step()``.
    :param input_fields: fields copied from the log before each step.
    :param output_fields: fields the step writes (recomputed); all other fields of the
        result are copied from the log (timing).
    :raises DataFormatError: if the log lacks an input field or the command field.
    """
    from controller.records import LOOP_GATING_FIELDS, PHASE_ARMING

    dtype = ctl.record.dtype
    n = len(records)
    for name in (*input_fields, command_field):
        if name not in (records.dtype.names or ()):
            raise DataFormatError(f"log has no field '{name}' needed for replay")
    out = np.zeros(n, dtype)
    for name in input_fields:
        out[name] = records[name]
    # the loop's gating: cycles it did not step (arming) and the factor it applied
    gated = all(f in (records.dtype.names or ()) for f in LOOP_GATING_FIELDS)
    if gated:
        stepped = records["phase"] != PHASE_ARMING
        scale = records["cmd_scale"].astype(np.float64)
    else:                                   # a log of a loop without gating: every cycle stepped
        stepped = np.ones(n, bool)
        scale = np.ones(n)
    todo = np.flatnonzero(stepped)
    step = ctl.step
    own_record = ctl.record
    t0 = time.perf_counter()
    try:
        # fast path: point the controller's record at row i of the result, so the step
        # reads the logged inputs there and writes its outputs in place
        if todo.size:
            i = int(todo[0])
            ctl.record = out[i:i + 1]
            out[command_field][i] = _SENTINEL           # must be overwritten by the step
            tau = np.float64(step())
            if out[command_field][i:i + 1].view(np.uint64)[0] != tau.view(np.uint64):
                raise _NoInPlace
            if progress is not None:
                progress(0, n)
            for k in range(1, todo.size):
                i = int(todo[k])
                ctl.record = out[i:i + 1]
                step()
                if progress is not None and not k & 0xFFFF:
                    progress(i, n)
    except _NoInPlace:
        # the controller does not step on whatever ``record`` refers to: copy in and out
        ctl.record = own_record
        ctl.reset()
        inp = out.copy()
        rec_u8 = own_record.view(np.uint8)
        in_u8 = inp.view(np.uint8).reshape(n, dtype.itemsize)
        out_u8 = out.view(np.uint8).reshape(n, dtype.itemsize)
        for k in range(todo.size):
            i = int(todo[k])
            rec_u8[:] = in_u8[i]
            step()
            out_u8[i] = rec_u8
            if progress is not None and not k & 0xFFFF:
                progress(i, n)
    finally:
        ctl.record = own_record
    wall = time.perf_counter() - t0
    if progress is not None:
        progress(n, n)
    for name in dtype.names:
        if name not in output_fields and name not in input_fields and name in (records.dtype.names or ()):
            out[name] = records[name]
    # the loop's command from the step's: gating factor, zero on any fault (as the daemon)
    cmd = out[command_field]
    faults = out["fault_bits"].astype(np.int64) if "fault_bits" in dtype.names else np.zeros(n, np.int64)
    if "ext_fault_bits" in dtype.names:
        faults |= out["ext_fault_bits"].astype(np.int64)
    with np.errstate(invalid="ignore", over="ignore"):
        cmd *= scale                        # vectorised controller.records.loop_command
    cmd[(faults != 0) | ~np.isfinite(cmd) | ~stepped] = 0.0
    a = records[command_field].astype(np.float64)
    b = out[command_field]
    differ = a.view(np.uint64) != b.view(np.uint64)
    dabs = np.abs(b - a)
    dabs[np.isnan(a) & np.isnan(b)] = 0.0
    dabs[np.isnan(dabs)] = np.inf
    first = int(np.argmax(differ)) if differ.any() else -1
    return ReplayResult(out, float(dabs.max()) if n else 0.0, int(differ.sum()), first, wall)


def _plot(logged: np.ndarray, whatif: np.ndarray, path: Path, title: str) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    names = [f for f in ("tau_m_cmd_Nm", "tau_in_des_Nm", "d_hat_Nm", "tau_fc_Nm") if f in whatif.dtype.names]
    step = max(1, len(logged) // 20000)
    t = logged["t_s"][::step] - logged["t_s"][0] if "t_s" in logged.dtype.names else np.arange(len(logged))[::step]
    fig, axes = plt.subplots(len(names), 1, figsize=(9, 2.2 * len(names)), sharex=True, squeeze=False)
    for ax, name in zip(axes[:, 0], names):
        ax.plot(t, logged[name][::step], lw=0.7, label="logged")
        ax.plot(t, whatif[name][::step], lw=0.7, label="what-if")
        ax.set_ylabel(name)
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(loc="upper right")
    axes[0, 0].set_title(title)
    axes[-1, 0].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def run(args: argparse.Namespace) -> int:
    """Run ``capstan replay``; returns 0, or 1 if a logged-config replay is not bit-exact.

    :raises DataFormatError: if the log is unreadable or lacks replay fields.
    :raises ConfigError: if the logged or override config is invalid.
    """
    from controller.log_reader import read_log, read_logs
    from controller.mcap_log import McapLog
    from controller.records import MEASUREMENT_FIELDS, STEP_OUTPUT_FIELDS
    from tools.log_progress import Progress

    paths = [Path(p) for p in args.log]
    t_start = time.perf_counter()
    big = sum(p.stat().st_size for p in paths if p.exists()) > 20_000_000
    bar = Progress("read  ", enabled=big and len(paths) == 1)
    data = read_log(paths[0], bar.update) if len(paths) == 1 else read_logs(paths)
    bar.done()
    read_s = time.perf_counter() - t_start
    if data.meta.get("file_index", "0") != "0":
        _log.warning("%s is not the first file of its run: the controller state at its start "
                     "is unknown, commands will differ", paths[0])
    if not data.config:
        raise DataFormatError(f"{paths[0]}: log stores no config; cannot rebuild the controller")
    cfg = data.config
    override = None
    if args.config:
        override = load_yaml(args.config)
        cfg = merge_config(cfg, override)
    t_build = time.perf_counter()
    ctl = build_controller(cfg)
    build_s = time.perf_counter() - t_build
    inputs = tuple(f for f in ("cycle", *MEASUREMENT_FIELDS) if f in ctl.record.dtype.names)
    n = len(data.records)
    bar = Progress("replay", enabled=n >= PROGRESS_MIN_CYCLES)
    res = replay_records(data.records, ctl, inputs, STEP_OUTPUT_FIELDS, progress=bar.update)
    bar.done()
    per_log_s = read_s + res.wall_s          # grows with the log; build_s is a fixed start-up
    duration_s = float(data.records["t_s"][-1] - data.records["t_s"][0]) if n > 1 else 0.0
    report: dict[str, Any] = {
        "log": [str(p) for p in paths], "cycles": n, "duration_s": duration_s,
        "truncated": data.truncated, "config": "override" if override is not None else "logged",
        "max_abs_dtau_m_Nm": res.max_abs_dtau_m_Nm, "cycles_different": res.n_different,
        "first_different_cycle": res.first_different, "step_wall_s": res.wall_s,
        "read_wall_s": read_s, "controller_build_s": build_s,
        "speed_x_realtime": duration_s / per_log_s if per_log_s > 0 else None,
    }
    if override is not None:
        out = Path(args.out) if args.out else paths[0].with_name(paths[0].stem + "_whatif.mcap")
        mlog = McapLog(out.parent, out.stem, res.replayed.dtype, yaml.safe_dump(cfg, sort_keys=False),
                       flush_interval_s=0, first_path=out,
                       extra_meta={"whatif_of": str(paths[0]),
                                   "override_yaml": yaml.safe_dump(override, sort_keys=False)})
        mlog.write_records(res.replayed)
        mlog.close()
        report["whatif_log"] = str(out)
        if not args.no_plot:
            report["plot"] = str(_plot(data.records, res.replayed, out.with_suffix(".png"),
                                       f"what-if ({Path(args.config).name}), open loop on logged measurements"))
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(f"log: {', '.join(report['log'])}: {n} cycles, {duration_s:.3f} s"
              f"{' (truncated)' if data.truncated else ''}")
        print(f"config: {report['config']}")
        print(f"max |dtau_m| = {res.max_abs_dtau_m_Nm:.6g} Nm; cycles different: {res.n_different}"
              + (f" (first at index {res.first_different})" if res.first_different >= 0 else ""))
        if report["speed_x_realtime"]:
            print(f"read {read_s:.3f} s + step {res.wall_s:.3f} s = {report['speed_x_realtime']:.0f}x "
                  f"real time (plus {build_s:.2f} s controller build/warm-up)")
        for key in ("whatif_log", "plot"):
            if key in report:
                print(f"{key.replace('_', ' ')}: {report[key]}")
    if override is None and res.n_different:
        _log.error("replay with the logged config is not bit-exact: %d cycles differ", res.n_different)
        return 1
    return 0
