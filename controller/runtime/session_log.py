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

from capstan.controller.law.records import LOG_FLOAT32_FIELDS
from capstan.controller.runtime.timing import WindowReport

#: one timing-statistics record per window (``/capstan/stats``), µs unless noted
STATS_DTYPE = np.dtype([
    ("t_s", "f8"), ("cycles", "u4"), ("late", "u4"), ("missed_total", "u8"), ("dropped_total", "u8"),
    ("jitter_p50_us", "f8"), ("jitter_p99_us", "f8"), ("jitter_p999_us", "f8"), ("jitter_max_us", "f8"),
    ("latency_p99_us", "f8"), ("compute_p50_us", "f8"), ("compute_p99_us", "f8"),
    ("compute_max_us", "f8"), ("success_rate", "f8"), ("gil_wait_max_us", "f8"),
    # command quality of the window (controller/runtime/command_quality.py): Nm, Nm per cycle, -, count, Nm
    ("cmd_std_Nm", "f8"), ("cmd_change_rms_Nm", "f8"), ("cmd_hf_share", "f8"), ("rate_limit_hits", "u4"),
    ("tau_in_std_Nm", "f8"),
])


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

    def close(self, timeout_s: float = 10.0) -> int | None:
        """Finish the log (writer drains and closes the file)."""


class NullSink:
    """A sink that keeps only counters and the fault events (tests, ``logging: none``)."""

    def __init__(self) -> None:
        self.pushed = 0
        self.stats: list[np.ndarray] = []
        self.faults: list[tuple[float, str, int]] = []
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

    def close(self, timeout_s: float = 10.0) -> int | None:
        self.closed = True
        return 0


def open_session(out_dir: Path, record_dtype: np.dtype, config: Any, ring_records: int,
                 fault_history_cycles: int, prefix: str = "capstan") -> Any:
    """Create the rings and start the writer process.

    The fields of :data:`capstan.controller.law.records.LOG_FLOAT32_FIELDS` that the record has are
    stored as float32 (recomputed by a replay, or integer-nanosecond timing).

    :param config: the daemon config mapping, stored as YAML in every log file.
    :returns: a started :class:`capstan.controller.log.writer.LogSession`.
    :raises OSError: if the rings or the log directory cannot be created.
    :raises LogWriterError: if the writer process does not start.
    """
    from capstan.controller.log.writer import LogSession
    out_dir.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump(config, sort_keys=False) if not isinstance(config, str) else config
    names = record_dtype.names or ()
    f32 = tuple(f for f in LOG_FLOAT32_FIELDS if f in names and record_dtype[f] == np.float64)
    session = LogSession(record_dtype, out_dir, config_yaml=text, stats_dtype=STATS_DTYPE,
                         capacity=ring_records, prefix=prefix, fault_history_n=fault_history_cycles,
                         float32_fields=f32)
    session.start()
    return session


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
