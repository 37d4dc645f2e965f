"""The daemon's side of logging: the log session it starts and the 1 Hz timing record.

The daemon pushes one cycle record per cycle and one :data:`STATS_DTYPE` record per
statistics window into :class:`capstan.controller.log.writer.LogSession` (shared-memory rings
drained by a writer process that writes MCAP); faults go to the event channel with
the last N cycles attached by the writer. :class:`NullSink` keeps the same interface
for tests and for runs without a log.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol

import numpy as np
import yaml

from capstan.controller.law.fingerprint import law_fingerprint
from capstan.controller.law.records import DERIVED_FROM_WIRE, LOG_FLOAT32_FIELDS, LOG_FLOAT32_QUANTA
from capstan.controller.runtime.link_report import LINK_STATS_FIELDS
from capstan.controller.runtime.timing import WindowReport

#: metadata record of the units the CiA 402 drive reported at start-up (drivers/canopen/drive_units.py)
DRIVE_UNITS_META = "capstan.drive_units"

#: one timing-statistics record per window (``/capstan/stats``), µs unless noted
STATS_DTYPE = np.dtype([
    ("t_s", "f8"), ("cycles", "u4"), ("late", "u4"), ("missed_total", "u8"), ("dropped_total", "u8"),
    ("jitter_p50_us", "f8"), ("jitter_p99_us", "f8"), ("jitter_p999_us", "f8"), ("jitter_max_us", "f8"),
    ("latency_p99_us", "f8"), ("compute_p50_us", "f8"), ("compute_p99_us", "f8"),
    ("compute_max_us", "f8"), ("success_rate", "f8"), ("gil_wait_max_us", "f8"),
    # TPDOs with statusword bit 11 (the drive limited the torque itself), since start
    ("drive_limit_total", "u8"),
    # command quality of the window (controller/runtime/command_quality.py): Nm, Nm per cycle, -, count, Nm
    ("cmd_std_Nm", "f8"), ("cmd_change_rms_Nm", "f8"), ("cmd_hf_share", "f8"), ("rate_limit_hits", "u4"),
    ("tau_in_std_Nm", "f8"),
] + LINK_STATS_FIELDS)


class LogSink(Protocol):
    """What the daemon needs from a log (LogSession satisfies it)."""

    def push(self, record: np.ndarray) -> bool:
        """Queue one cycle record without blocking; False if dropped."""

    def push_stats(self, record: np.ndarray) -> bool:
        """Queue one stats record."""

    def fault(self, t_s: float, reason: str, code: int = 0, n_cycles: int | None = None) -> bool:
        """Queue a fault event (the last ``n_cycles`` records are attached)."""

    @property
    def dropped(self) -> int:
        """Cycle records dropped so far."""

    def writer_alive(self) -> bool:
        """True while the writer runs."""

    def metadata(self, name: str, values: dict[str, Any]) -> bool:
        """Queue a metadata record for every log file (e.g. the wire derivations)."""

    def supervise(self) -> int:
        """Check the writer about once a second; a WriterHealth value (2 = lost: stop)."""

    def close(self, timeout_s: float = 10.0) -> int | None:
        """Finish the log (writer drains and closes the file)."""


class NullSink:
    """A sink that keeps only counters and the fault events (tests, ``logging: none``)."""

    def __init__(self) -> None:
        self.pushed = 0
        self.stats: list[np.ndarray] = []
        self.faults: list[tuple[float, str, int]] = []
        self.meta: dict[str, dict[str, Any]] = {}
        self.closed = False

    def push(self, record: np.ndarray) -> bool:
        self.pushed += 1
        return True

    def push_stats(self, record: np.ndarray) -> bool:
        self.stats.append(record.copy())
        return True

    def fault(self, t_s: float, reason: str, code: int = 0, n_cycles: int | None = None) -> bool:
        self.faults.append((t_s, reason, code))
        return True

    @property
    def dropped(self) -> int:
        return 0

    def writer_alive(self) -> bool:
        return True

    def metadata(self, name: str, values: dict[str, Any]) -> bool:
        self.meta[name] = dict(values)
        return True

    def supervise(self) -> int:
        return 0

    def close(self, timeout_s: float = 10.0) -> int | None:
        self.closed = True
        return 0


def open_session(out_dir: Path, record_dtype: np.dtype, config: Any, ring_records: int,
                 fault_history_cycles: int, prefix: str = "capstan", wire: bool = False,
                 imu_rate_float32: bool = False, on_writer_loss: str = "restart",
                 max_writer_restarts: int = 3, rotate_size_MB: float = 0.0, rotate_age_s: float = 0.0,
                 keep_newest_GB: float = 0.0) -> Any:
    """Create the rings and start the writer process.

    The fields of :data:`capstan.controller.law.records.LOG_FLOAT32_FIELDS` that the record has are
    stored as float32 (recomputed by a replay, or integer-nanosecond timing), the step
    intermediates rounded to the quanta of :data:`capstan.controller.law.records.LOG_FLOAT32_QUANTA`.

    :param wire: store the measurements as the devices sent them: the SI fields of
        :data:`capstan.controller.law.records.DERIVED_FROM_WIRE` are left out (a reader
        rebuilds them with the ``capstan.derivations`` metadata the daemon sends with
        :func:`send_derivations` once the devices are started).
    :param imu_rate_float32: the IMU sends its rate of turn as float32, so the wire
        field is stored as float32 (exact).
    :param rotate_size_MB / rotate_age_s / keep_newest_GB: rotation and retention (0 = off).
    :param on_writer_loss / max_writer_restarts: writer supervision policy
        (:class:`capstan.controller.log.session.LogSession`).

    :param config: the daemon config mapping, stored as YAML in every log file.
    :returns: a started :class:`capstan.controller.log.writer.LogSession`.
    :raises OSError: if the rings or the log directory cannot be created.
    :raises LogWriterError: if the writer process does not start.
    """
    from capstan.controller.log.session import LogSession
    out_dir.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump(config, sort_keys=False) if not isinstance(config, str) else config
    names = record_dtype.names or ()
    f32 = tuple(f for f in LOG_FLOAT32_FIELDS if f in names and record_dtype[f] == np.float64)
    drop: tuple[str, ...] = ()
    if wire:
        drop = tuple(f for f, src in DERIVED_FROM_WIRE.items() if f in names and src in names)
        if imu_rate_float32 and "imu_rate_rad_s" in names:
            f32 += ("imu_rate_rad_s",)
    session = LogSession(record_dtype, out_dir, config_yaml=text, stats_dtype=STATS_DTYPE,
                         capacity=ring_records, prefix=prefix, fault_history_n=fault_history_cycles,
                         float32_fields=f32, drop_fields=drop, on_writer_loss=on_writer_loss,
                         max_writer_restarts=max_writer_restarts, rotate_size_bytes=int(rotate_size_MB * 1e6),
                         rotate_time_s=rotate_age_s, keep_bytes=int(keep_newest_GB * 1e9),
                         float32_quanta={f: q for f, q in LOG_FLOAT32_QUANTA.items() if f in f32},
                         log_meta={"law_sha256": law_fingerprint()})
    session.start()
    return session


def logged_config(raw: Any, controller: Any) -> Any:
    """The config a log stores: the daemon's mapping as written, with the ``controller``
    section replaced by the resolved one of the controller that runs (every value explicit,
    ``ControllerConfig.to_mapping``), so a replay rebuilds the same law even after a default
    changes. ``raw`` is returned as it is for a controller without a resolved config."""
    cfg = getattr(controller, "cfg", None)
    if not isinstance(raw, dict) or not hasattr(cfg, "to_mapping"):
        return raw
    return {**raw, "controller": cfg.to_mapping()}


def wire_capable(devices: Any) -> bool:
    """True if every device says how its SI values follow from its wire values
    (``derivations()``), so the log can store wire values only."""
    return all(callable(getattr(d, "derivations", None)) for d in (devices.motor, devices.imu, devices.load_cells))


def send_derivations(sink: Any, devices: Any) -> None:
    """Send the started devices' wire -> SI derivations (and the loop clock's) to the log
    as the ``capstan.derivations`` metadata record, and the units the drive reported as
    ``capstan.drive_units``."""
    from capstan.controller.log.mcap_log import DERIVATIONS_META
    from capstan.models.common.wire_units import NS_TO_S, Derivation
    items = [Derivation("t_s", "t_ns", NS_TO_S)]
    for dev in (devices.motor, devices.imu, devices.load_cells):
        get = getattr(dev, "derivations", None)
        if callable(get):
            items += get()
    put = getattr(sink, "metadata", None)
    if callable(put):
        put(DERIVATIONS_META, {"derivations": [d.to_json() for d in items]})
        units = getattr(devices.motor, "drive_units", None)
        if callable(getattr(units, "to_json", None)):   # what the drive reported at start-up
            put(DRIVE_UNITS_META, units.to_json())


def newest_log(out_dir: Path, prefix: str = "capstan", since_s: float = 0.0) -> Path | None:
    """The most recently modified ``{prefix}_*.mcap`` in ``out_dir`` (modified after ``since_s``)."""
    files = [p for p in Path(out_dir).glob(f"{prefix}_*.mcap") if p.stat().st_mtime >= since_s]
    return max(files, key=lambda p: p.stat().st_mtime) if files else None


def fill_stats(buf: np.ndarray, t_s: float, rep: WindowReport, missed_total: int, dropped_total: int,
               cmd: Any = None) -> None:
    """Write one window report (and the window's :class:`CommandReport` ``cmd``) into the
    (1,) stats buffer."""
    b = buf[0]
    if cmd is not None:
        b["cmd_std_Nm"], b["cmd_change_rms_Nm"] = cmd.cmd_std_Nm, cmd.cmd_change_rms_Nm
        b["cmd_hf_share"], b["rate_limit_hits"] = cmd.cmd_hf_share, cmd.rate_limit_hits
        b["tau_in_std_Nm"] = cmd.tau_in_std_Nm
    b["t_s"], b["cycles"], b["late"] = t_s, rep.cycles, rep.late
    b["missed_total"], b["dropped_total"] = missed_total, dropped_total
    b["jitter_p50_us"], b["jitter_p99_us"] = rep.jitter_p50_us, rep.jitter_p99_us
    b["jitter_p999_us"], b["jitter_max_us"] = rep.jitter_p999_us, rep.jitter_max_us
    b["latency_p99_us"], b["compute_p50_us"] = rep.latency_p99_us, rep.compute_p50_us
    b["compute_p99_us"], b["compute_max_us"] = rep.compute_p99_us, rep.compute_max_us
    b["success_rate"] = rep.success_rate
    b["gil_wait_max_us"] = rep.gil_wait_max_us
