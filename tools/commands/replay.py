"""``capstan replay LOG.mcap [--config OVERRIDE.yaml] [--json]``: re-run the controller on
the logged measurements.

With the logged config the replayed commands must equal the logged ones bit for bit;
the command reports max |dtau_m| (0 expected) and exits 1 otherwise, saying whether the
control law changed since the log was written (the log's ``law_sha256`` against this
build's). With an override (a YAML mapping merged key by key over the logged config) it
writes a what-if log and a plot. The replay is open loop: the plant does not react to the what-if commands, the
logged measurements are fed unchanged.

Only the fields the loop writes before the step (``cycle`` and
``controller.records.MEASUREMENT_FIELDS``) are copied from the log into the controller's
record; everything the step computes is recomputed from a fresh controller.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from capstan.controller.law.fingerprint import UNAVAILABLE, law_fingerprint
from capstan.models.common.config_tools import load_yaml
from capstan.models.common.errors import DataFormatError
from capstan.tools.offline.replay import build_controller, merge_config, replay_records

HELP = "re-run the controller on a logged MCAP file (bit-exact check, or what-if with --config)"
_log = logging.getLogger(__name__)

#: progress bar when the log is longer than this [cycles]
PROGRESS_MIN_CYCLES = 300_000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``capstan replay``."""
    parser.add_argument("log", nargs="+", help="capstan MCAP log (several = one rotated run, in order)")
    parser.add_argument("--config", help="override YAML merged over the logged config (what-if)")
    parser.add_argument("--out", help="what-if log path (default: LOG_whatif.mcap next to the log)")
    parser.add_argument("--plot", action=argparse.BooleanOptionalAction, default=True,
                        help="write the what-if plot (default: yes)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


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
    from capstan.controller.log import wire_decode
    from capstan.controller.log.reader import read_logs
    from capstan.tools.offline.archive import read_any
    from capstan.controller.log.mcap_log import McapLog
    from capstan.controller.law.records import LOOP_GATING_FIELDS, MEASUREMENT_FIELDS, STEP_OUTPUT_FIELDS
    from capstan.tools.offline.progress import Progress

    paths = [Path(p) for p in args.log]
    # the bit-exact check reads only what the step takes and what it is compared with;
    # a what-if run reads every field (its log keeps the logged timing fields)
    fields = None if args.config else ("cycle", "t_s", "tau_m_cmd_Nm", *MEASUREMENT_FIELDS, *LOOP_GATING_FIELDS)
    t_load = time.perf_counter()
    wire_decode.warmup()                     # a fixed start-up, like the controller build
    decoder_load_s = time.perf_counter() - t_load
    t_start, cpu_start = time.perf_counter(), time.process_time()
    big = sum(p.stat().st_size for p in paths if p.exists()) > 20_000_000
    bar = Progress("read  ", enabled=big and len(paths) == 1)
    data = read_any(paths[0], bar.update, fields) if len(paths) == 1 else read_logs(paths, fields)
    bar.done()
    read_s = time.perf_counter() - t_start
    read_cpu_s = time.process_time() - cpu_start
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
    step_cpu_s = res.cpu_s
    bar.done()
    per_log_s = read_s + res.wall_s          # grows with the log; build_s, decoder_load_s: fixed start-up
    duration_s = float(data.records["t_s"][-1] - data.records["t_s"][0]) if n > 1 else 0.0
    report: dict[str, Any] = {
        "log": [str(p) for p in paths], "cycles": n, "duration_s": duration_s,
        "truncated": data.truncated, "config": "override" if override is not None else "logged",
        "max_abs_dtau_m_Nm": res.max_abs_dtau_m_Nm, "cycles_different": res.n_different,
        "first_different_cycle": res.first_different, "step_wall_s": res.wall_s,
        "read_wall_s": read_s, "controller_build_s": build_s, "decoder_load_s": decoder_load_s,
        "speed_x_realtime": duration_s / per_log_s if per_log_s > 0 else None,
        # CPU seconds of this process (all threads) for the same two parts: what the
        # replay costs, apart from how much of a CPU a loaded machine gave it
        "read_cpu_s": read_cpu_s, "step_cpu_s": step_cpu_s,
        "speed_x_realtime_cpu": (duration_s / (read_cpu_s + step_cpu_s)
                                 if read_cpu_s + step_cpu_s > 0 else None),
        # which control law wrote the log and which replays it (None: the log does not say)
        "law_sha256_logged": data.meta.get("law_sha256"), "law_sha256_replay": law_fingerprint(),
    }
    report["law_changed"] = law_changed(report["law_sha256_logged"], report["law_sha256_replay"])
    if override is not None:
        out = Path(args.out) if args.out else paths[0].with_name(paths[0].stem + "_whatif.mcap")
        mlog = McapLog(out.parent, out.stem, res.replayed.dtype, yaml.safe_dump(cfg, sort_keys=False),
                       flush_interval_s=0, first_path=out,
                       extra_meta={"whatif_of": str(paths[0]), "law_sha256": law_fingerprint(),
                                   "override_yaml": yaml.safe_dump(override, sort_keys=False)})
        mlog.write_records(res.replayed)
        mlog.close()
        report["whatif_log"] = str(out)
        if args.plot:
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
                  f"real time (plus {build_s:.2f} s controller build/warm-up, {decoder_load_s:.2f} s decoder load)")
        if report["law_changed"] is not None:
            which = "changed since the log was written" if report["law_changed"] else "the one that wrote the log"
            print(f"control law: {which} (law_sha256 {report['law_sha256_replay'][:12]})")
        for key in ("whatif_log", "plot"):
            if key in report:
                print(f"{key.replace('_', ' ')}: {report[key]}")
    if override is None and res.n_different:
        _log.error("replay with the logged config is not bit-exact: %d cycles differ; %s",
                   res.n_different, law_verdict(report["law_sha256_logged"], report["law_sha256_replay"]))
        return 1
    return 0


def law_changed(logged: str | None, replay: str) -> bool | None:
    """Whether the control law changed since the log was written, from the law fingerprints of
    the log and of this build (:func:`capstan.controller.law.fingerprint.law_fingerprint`);
    None when either is unknown."""
    if not logged or UNAVAILABLE in (logged, replay):
        return None
    return logged != replay


def law_verdict(logged: str | None, replay: str) -> str:
    """What a replay that is not bit-exact means (:func:`law_changed`)."""
    changed = law_changed(logged, replay)
    if changed is None:
        return ("the log does not record which control law wrote it (law_sha256), so a law "
                "change since cannot be told from an altered log")
    if changed:
        return (f"the log was written by a different control law (law_sha256 {logged[:12]} in the "
                f"log, {replay[:12]} here): the difference is the law's change; replay with the "
                "capstan version that wrote the log to check the log itself")
    return ("the control law is the same as the one that wrote the log (law_sha256 "
            f"{logged[:12]}): the log's inputs or commands were altered, or replay is wrong")
