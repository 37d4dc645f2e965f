"""Producer side of the live log: the rings and the supervised writer process.

::

    log = LogSession(RECORD_DTYPE, "logs/", config_yaml=text)
    log.start()                      # creates the rings, spawns `python -m capstan.controller.log.writer`
    log.push(ctl.record)             # every cycle: O(1), never blocks, drops when full
    log.fault(t_s, "stale IMU", code=bits)   # writer attaches its last N cycle records
    log.supervise()                  # about once a second: restarts a dead writer (policy)
    log.close()                      # writer drains, finishes the file (valid summary), exits

Supervision: a writer that dies (killed, crashed) is restarted into a new file, without
blocking the loop (the ring keeps the records meanwhile). The new writer continues at the
ring's read position and writes a ``WRITER_RESTARTED`` event before its first record,
naming the missing cycles exactly: those after the last cycle the dead writer had handed
to the OS (the ring header says which) up to the first one it reads. ``dropped`` counts
ring drops plus the records a dead writer had taken but not written, so it equals the
cycles missing from the files. With ``on_writer_loss="stop"``, or after
``max_writer_restarts`` restarts, :meth:`supervise` reports :attr:`WriterHealth.LOST` and
the caller stops (the daemon ramps the torque to zero).
"""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import time
from enum import IntEnum
from pathlib import Path
from collections.abc import Mapping
from typing import Any

import numpy as np

from capstan.controller.log.mcap_log import DEFAULT_FLUSH_INTERVAL_S, EventKind, stored_dtype
from capstan.controller.log.ring import LogRing, remove_stale_rings
from capstan.controller.log.schema import LogFormatError, build_layout
from capstan.models.common.errors import CapstanError, DataFormatError

_log = logging.getLogger(__name__)

#: what to do when the writer process dies
WRITER_LOSS_POLICIES = ("restart", "stop")


class WriterHealth(IntEnum):
    """Result of :meth:`LogSession.supervise`."""

    OK = 0            #: the writer runs (or the session is closing)
    RESTARTED = 1     #: the writer had died and a new one was started into a new file
    LOST = 2          #: the writer died and is not restarted (policy or too many failures)


class LogWriterError(CapstanError):
    """The log writer process could not be started or did not become ready."""


#: zstd level of the live log: the knee of file size against writer CPU for cycle
#: records (``tools/bench/logs.py --levels`` prints the curve: levels 3..12 within 1 %
#: of each other, 15 about 12 % smaller at 30-40 us CPU per record, i.e. 3-4 % of one CPU
#: at 1 kHz, 19 no smaller at twice the CPU)
LIVE_ZSTD_LEVEL = 15

#: one metadata record passed from the daemon to the writer: name, JSON object of strings
META_DTYPE = np.dtype([("name", "S64"), ("json", "S16320")])

#: fixed-size event record passed from the daemon to the writer
EVENT_DTYPE = np.dtype([("t_s", "<f8"), ("kind", "<u4"), ("n_cycles", "<u4"), ("code", "<u8"),
                        ("reason", "S240")])


def _normal_scheduling(pid: int, cpus: frozenset[int] | None = None) -> None:
    """A writer restarted from the real-time loop inherits its SCHED_FIFO priority and CPU
    pinning: give it normal scheduling on ``cpus`` (default every CPU; lowering is always
    permitted)."""
    try:
        if os.sched_getscheduler(pid) != os.SCHED_OTHER:
            os.sched_setscheduler(pid, os.SCHED_OTHER, os.sched_param(0))
        os.sched_setaffinity(pid, cpus or range(os.cpu_count() or 1))
    except (OSError, AttributeError) as exc:     # the process may be gone already
        _log.debug("log writer %d: scheduling not reset: %s", pid, exc)


class LogSession:
    """Producer-side handle: owns the rings and the writer process.

    :param record_dtype: dtype of the cycle records.
    :param out_dir: log directory.
    :param config_yaml: daemon config (YAML text) stored in every log file.
    :param stats_dtype: dtype of 1 Hz stats records, or None.
    :param capacity: ring slots (at 1 kHz, 8192 slots is 8 s of writer stall).
    :param fault_history_n: cycle records attached to a fault event.
    :param flush_interval_s: chunk close period (what a writer kill can lose).
    :param rotate_size_bytes / rotate_time_s: rotation policy (0 = never).
    :param keep_bytes: retention: keep the newest files up to this many bytes (0 = all).
    :param float32_fields: float64 fields stored rounded to float32 (see
        :func:`capstan.controller.log.schema.build_layout`); never replay inputs or the command.
    :param zstd_level: zstd level of the chunks (1..22).
    :param float32_quanta: float32 field -> power-of-two quantum it is stored rounded to
        (:func:`capstan.controller.log.schema.quantize_float32`).
    :param drop_fields: record fields not stored (rebuilt by readers from wire fields).
    :param on_writer_loss: ``"restart"`` (a new writer, a new file, the gap as an event)
        or ``"stop"`` (:meth:`supervise` reports LOST at the first death).
    :param max_writer_restarts: restarts allowed before the writer counts as LOST.
    :param log_meta: more key -> text pairs for every file's ``capstan.log`` metadata record
        (e.g. the law's fingerprint).
    :raises LogFormatError: if the dtype cannot be logged or a float32 field or quantum is invalid.
    :raises ValueError: on a zstd level out of 1..22, an unknown policy or a negative
        restart count.
    """

    def __init__(self, record_dtype: np.dtype, out_dir: str | Path, config_yaml: str = "",
                 stats_dtype: np.dtype | None = None, capacity: int = 8192, prefix: str = "capstan",
                 fault_history_n: int = 1000, flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
                 rotate_size_bytes: int = 0, rotate_time_s: float = 0.0,
                 compression: str = "zstd", float32_fields: tuple[str, ...] = (),
                 zstd_level: int = LIVE_ZSTD_LEVEL, drop_fields: tuple[str, ...] = (),
                 on_writer_loss: str = "restart", max_writer_restarts: int = 3, keep_bytes: int = 0,
                 float32_quanta: Mapping[str, float] | None = None,
                 log_meta: Mapping[str, str] | None = None) -> None:
        # fail here, not in the writer
        build_layout(stored_dtype(np.dtype(record_dtype), tuple(drop_fields)), "capstan.Cycle",
                     tuple(float32_fields), float32_quanta)
        if not 1 <= int(zstd_level) <= 22:
            raise ValueError(f"zstd level must be 1..22, got {zstd_level}")
        if on_writer_loss not in WRITER_LOSS_POLICIES:
            raise ValueError(f"on_writer_loss must be one of {', '.join(WRITER_LOSS_POLICIES)}, "
                             f"got {on_writer_loss!r}")
        if int(max_writer_restarts) < 0:
            raise ValueError(f"max_writer_restarts must be >= 0, got {max_writer_restarts}")
        self.on_writer_loss = on_writer_loss
        self.max_writer_restarts = int(max_writer_restarts)
        #: writer deaths so far, and records a dead writer had taken but not written
        self.writer_failures = 0
        self.lost_in_writers = 0
        self.lost = False
        self._closing = False
        self._read_at_spawn = 0
        self._last_durable_cycle = -1
        self._sent_meta: dict[str, dict[str, Any]] = {}
        self._final_dropped: int | None = None
        self.lost_reason = ""
        self.out_dir = Path(out_dir)
        self.prefix = prefix
        self.fault_history_n = fault_history_n
        if self.out_dir.is_dir():              # logs a crash of daemon and writer left without a footer
            from capstan.controller.log.recover import recover_cut_logs
            for res in recover_cut_logs(self.out_dir, prefix):
                _log.warning("recovered %s, cut off by a crash: %d chunks, %d messages kept", res.path,
                             res.chunks, res.messages)
        stale = remove_stale_rings()
        if stale:
            _log.warning("removed %d shared-memory ring(s) of dead processes: %s", len(stale),
                         ", ".join(p.name for p in stale))
        self.cycle = LogRing.create(record_dtype, capacity, meta={"config_yaml": config_yaml,
                                                                       "log_meta": dict(log_meta or {})})
        self.events = LogRing.create(EVENT_DTYPE, 256)
        self.stats = LogRing.create(stats_dtype, 64) if stats_dtype is not None else None
        self.meta = LogRing.create(META_DTYPE, 8)
        self._meta_rec = np.zeros(1, META_DTYPE)
        self._ev = np.zeros(1, EVENT_DTYPE)
        self._args = ["--prefix", prefix, "--flush-interval-s", str(flush_interval_s),
                      "--rotate-size-bytes", str(int(rotate_size_bytes)),
                      "--rotate-time-s", str(rotate_time_s), "--compression", compression,
                      "--fault-history", str(fault_history_n),
                      "--float32-fields", ",".join(float32_fields), "--zstd-level", str(int(zstd_level)),
                      "--drop-fields", ",".join(drop_fields), "--keep-bytes", str(int(keep_bytes)),
                      "--float32-quanta", json.dumps({k: float(v) for k, v in (float32_quanta or {}).items()})]
        self.proc: subprocess.Popen | None = None
        #: CPUs the writer process runs on (None: every CPU), see :meth:`keep_writer_on`
        self.writer_cpus: frozenset[int] | None = None

    def keep_writer_on(self, cpus: frozenset[int]) -> None:
        """Run the writer (now and after any restart) on ``cpus`` only: the daemon keeps it off
        the loop's pinned CPUs, where its encoding (~1/3 of a core at 1 kHz) would delay cycles.
        An empty set leaves it on every CPU."""
        self.writer_cpus = frozenset(cpus) or None
        if self.proc is not None and self.proc.poll() is None:
            _normal_scheduling(self.proc.pid, self.writer_cpus)

    def start(self, ready_timeout_s: float = 10.0) -> None:
        """Spawn the writer process (``python -m capstan.controller.log.writer``) and wait until
        it has its signal handlers and first file open.

        :raises LogWriterError: if the writer exits or is not ready within ``ready_timeout_s``.
        """
        self._spawn()
        deadline = time.monotonic() + ready_timeout_s
        while not self.cycle.consumer_ready:
            if self.proc.poll() is not None:
                raise LogWriterError(f"log writer exited at start-up with code {self.proc.returncode}")
            if time.monotonic() > deadline:
                raise LogWriterError(f"log writer not ready after {ready_timeout_s} s")
            time.sleep(0.01)

    def _spawn(self, *gap_args: str) -> None:
        cmd = [sys.executable, "-m", "capstan.controller.log.writer", "--ring", self.cycle.name,
               "--events-ring", self.events.name, "--meta-ring", self.meta.name, "--out-dir", str(self.out_dir),
               "--parent-pid", str(os.getpid()), *self._args, *gap_args]
        if self.stats is not None:
            cmd += ["--stats-ring", self.stats.name]
        self.cycle.reset_consumer()
        self._read_at_spawn = self.cycle.read_count
        self.proc = subprocess.Popen(cmd)
        _normal_scheduling(self.proc.pid, self.writer_cpus)

    def _newest_file(self) -> Path | None:
        files = list(self.out_dir.glob(f"{self.prefix}_*.mcap"))
        return max(files, key=lambda f: f.stat().st_mtime) if files else None

    def _recover_newest(self) -> None:
        from capstan.controller.log.recover import recover_log
        path = self._newest_file()
        if path is None:
            return
        try:
            recover_log(path)
        except (DataFormatError, OSError) as exc:
            _log.error("could not recover %s after the writer died: %s", path, exc)

    def supervise(self) -> WriterHealth:
        """Check the writer (call about once a second, from the loop: never blocks).

        A dead writer is counted; under the ``restart`` policy and within
        ``max_writer_restarts`` a new one is spawned (not waited for) that first rewrites
        the dead writer's file into a valid indexed one
        (:func:`capstan.controller.log.recover.recover_log`), then writes the gap as a
        ``WRITER_RESTARTED`` event into its new file, and the metadata sent so far again.
        """
        proc = self.proc
        if proc is None or self._closing:
            return WriterHealth.LOST if self.lost else WriterHealth.OK
        code = proc.poll()
        if code is None:
            return WriterHealth.OK
        durable, last_cycle = self.cycle.durable
        lost = max(0, self.cycle.read_count - self._read_at_spawn - durable)
        self.lost_in_writers += lost
        self.writer_failures += 1
        if durable:
            self._last_durable_cycle = last_cycle
        how = f"exit code {code}"
        if code < 0:
            try:
                how = f"killed by {signal.Signals(-code).name}"
            except ValueError:
                how = f"killed by signal {-code}"
        reason = (f"log writer pid {proc.pid} died ({how}); {lost} records it had not written are lost, "
                  f"{self.cycle.dropped} dropped from the ring so far")
        if self.on_writer_loss == "stop" or self.writer_failures > self.max_writer_restarts:
            why = ("policy on_writer_loss: stop" if self.on_writer_loss == "stop"
                   else f"{self.writer_failures} writer failures, at most {self.max_writer_restarts} restarts")
            _log.error("%s; not restarted (%s)", reason, why)
            self.proc, self.lost = None, True
            self.lost_reason = f"{reason}; not restarted ({why})"
            return WriterHealth.LOST
        _log.error("%s; restarting the writer into a new file (restart %d of at most %d)", reason,
                   self.writer_failures, self.max_writer_restarts)
        newest = self._newest_file()
        cut = ["--recover", str(newest)] if newest is not None else []
        self._spawn("--gap-after-cycle", str(self._last_durable_cycle), "--gap-reason", reason[:200], *cut)
        for name, values in self._sent_meta.items():
            self._push_meta(name, values)
        return WriterHealth.RESTARTED

    def push(self, record: np.ndarray | np.void) -> bool:
        """Queue one cycle record; False if dropped (ring full)."""
        return self.cycle.push(record)

    def push_stats(self, record: np.ndarray | np.void) -> bool:
        """Queue one stats record (no-op False without a stats dtype)."""
        return self.stats.push(record) if self.stats is not None else False

    def fault(self, t_s: float, reason: str, code: int = 0, n_cycles: int | None = None) -> bool:
        """Queue a fault event; the writer attaches the last ``n_cycles`` records up to ``t_s``.
        Push the faulting cycle's record first."""
        return self.event(t_s, EventKind.FAULT, reason, code,
                          self.fault_history_n if n_cycles is None else n_cycles)

    def event(self, t_s: float, kind: EventKind, reason: str, code: int = 0, n_cycles: int = 0) -> bool:
        """Queue any event for ``/capstan/events``."""
        e = self._ev
        e["t_s"], e["kind"], e["code"], e["n_cycles"] = t_s, int(kind), code, n_cycles
        e["reason"] = reason.encode()[:240]
        return self.events.push(e)

    def metadata(self, name: str, values: dict[str, Any]) -> bool:
        """Queue a metadata record (``name`` -> JSON-serialisable mapping) for the current
        and every later log file; False if the metadata ring is full.

        :raises LogFormatError: if the name or the JSON text is too long for one slot.
        """
        text = json.dumps(values).encode()
        if len(text) > META_DTYPE["json"].itemsize or len(name.encode()) > META_DTYPE["name"].itemsize:
            raise LogFormatError(f"metadata {name!r}: {len(text)} bytes of JSON do not fit one slot "
                                 f"({META_DTYPE['json'].itemsize})")
        self._sent_meta[name] = dict(values)
        return self._push_meta(name, values)

    def _push_meta(self, name: str, values: dict[str, Any]) -> bool:
        text = json.dumps(values).encode()
        m = self._meta_rec
        m["name"], m["json"] = name.encode(), text
        return self.meta.push(m)

    @property
    def dropped(self) -> int:
        """Cycle records missing from the files so far: dropped from a full ring, plus
        those a dead writer had taken but not written."""
        if self._final_dropped is not None:
            return self._final_dropped
        unread = self.cycle.written - self.cycle.read_count if self.lost else 0   # never reach a file
        return self.cycle.dropped + self.lost_in_writers + unread

    def writer_alive(self) -> bool:
        """True while the writer process runs (check it about once a second)."""
        return self.proc is not None and self.proc.poll() is None

    def close(self, timeout_s: float = 10.0) -> int | None:
        """Close the rings, wait for the writer to finish the file; returns its exit code
        (None if it had to be killed after ``timeout_s``)."""
        self.supervise()                     # a writer that died since the last check is counted
        self._closing = True
        self.cycle.close_producer()
        code: int | None = None
        if self.proc is not None:
            try:
                code = self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                _log.error("log writer did not finish in %.1f s; terminating it", timeout_s)
                self.proc.terminate()
                try:
                    self.proc.wait(timeout=2.0)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait()
        self._final_dropped = self.dropped
        if self.lost:                         # nobody replaced the dead writer: repair its file now
            self._recover_newest()
        for ring in (self.cycle, self.events, self.stats, self.meta):
            if ring is not None:
                ring.close()
        return code


