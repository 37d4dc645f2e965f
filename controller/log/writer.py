"""The log writer process: drains the shared-memory rings and writes MCAP.

Producer side (the daemon)::

    log = LogSession(RECORD_DTYPE, "logs/", config_yaml=text)
    log.start()                      # creates the rings, spawns `python -m capstan.controller.log.writer`
    log.push(ctl.record)             # every cycle: O(1), never blocks, drops when full
    log.fault(t_s, "stale IMU", code=bits)   # writer attaches its last N cycle records
    log.close()                      # writer drains, finishes the file (valid summary), exits

Writer side (this module run as a program) loops: drain the cycle ring, then stats,
then events (a fault pushed after its cycle record therefore finds that record in the
history), report new drops (logged and written as an event at most once a second),
close a chunk every ``flush_interval_s`` and rotate files. It stops cleanly, leaving a
valid MCAP file with summary, on SIGTERM, when the producer closes the ring, or when
the producer process is gone (then a PRODUCER_LOST event is written). SIGINT is
ignored: Ctrl-C in a terminal reaches the whole process group, and the daemon must be
the one to decide when logging ends.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from capstan.controller.log.ring import LogRing
from capstan.controller.log.mcap_log import DEFAULT_FLUSH_INTERVAL_S, EventKind, McapLog, stored_dtype
from capstan.controller.log.schema import LogFormatError, build_layout
from capstan.models.common.errors import CapstanError

_log = logging.getLogger(__name__)

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


class _History:
    """Circular buffer of the last ``n`` records seen by the writer."""

    def __init__(self, dtype: np.dtype, n: int) -> None:
        self.buf = np.zeros(max(n, 1), dtype)
        self.count = 0

    def add(self, recs: np.ndarray) -> None:
        n = len(self.buf)
        if len(recs) >= n:
            self.buf[:] = recs[-n:]
            self.count = n                  # oldest at index 0
            return
        pos = self.count % n
        first = min(len(recs), n - pos)
        self.buf[pos:pos + first] = recs[:first]
        self.buf[:len(recs) - first] = recs[first:]
        self.count += len(recs)

    def last(self, n: int, t_max: float | None = None, time_field: str = "",
             newer: np.ndarray | None = None) -> np.ndarray:
        """The last ``n`` records (of history followed by ``newer``) with time <= ``t_max``."""
        size = len(self.buf)
        have = min(self.count, size)
        pos = self.count % size
        ordered = np.concatenate([self.buf[pos:], self.buf[:pos]])[size - have:]
        if newer is not None and len(newer):
            ordered = np.concatenate([ordered, newer])
        if t_max is not None and time_field:
            ordered = ordered[ordered[time_field] <= t_max]
        return ordered[-n:] if n > 0 else ordered[:0]


def _alive(pid: int) -> bool:
    """True if process ``pid`` exists and is not a zombie."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return True


def run_writer(cycle: LogRing, out_dir: str | Path, events: LogRing | None = None,
               stats: LogRing | None = None, prefix: str = "capstan", rotate_size_bytes: int = 0,
               rotate_time_s: float = 0.0, flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
               compression: str = "zstd", fault_history_n: int = 1000, poll_s: float = 0.005,
               parent_pid: int = 0, stop_flag: list[bool] | None = None,
               float32_fields: tuple[str, ...] = (), zstd_level: int = LIVE_ZSTD_LEVEL,
               meta: LogRing | None = None, drop_fields: tuple[str, ...] = ()) -> McapLog:
    """Drain the rings into MCAP until the producer closes, dies, or ``stop_flag[0]``.

    :returns: the closed :class:`McapLog` (``files``, ``records_written``).
    :raises LogFormatError: if the record dtype cannot be logged.
    :raises ValueError: on an unknown compression or a zstd level out of 1..22.
    """
    stop_flag = stop_flag if stop_flag is not None else [False]
    config_yaml = str(cycle.meta.get("config_yaml", ""))
    mlog = McapLog(out_dir, prefix, cycle.dtype, config_yaml,
                   stats_dtype=stats.dtype if stats is not None else None,
                   rotate_size_bytes=rotate_size_bytes, rotate_time_s=rotate_time_s,
                   flush_interval_s=flush_interval_s, compression=compression,
                   float32_fields=float32_fields, zstd_level=zstd_level, drop_fields=drop_fields)
    hist = _History(cycle.dtype, fault_history_n)
    cycle.set_consumer_ready()
    producer = parent_pid or cycle.producer_pid
    reported_drops, last_drop_report = 0, 0.0
    why = "producer closed the ring"
    try:
        while True:
            finished = cycle.closed          # read before draining: nothing can follow it
            if meta is not None:             # metadata first: it describes the records
                for m in meta.read_batch():
                    _write_metadata(mlog, m)
            # events first: a fault's cycle record was pushed before the fault, so it is
            # in the history or in the batch read next
            evs = events.read_batch() if events is not None else None
            recs = cycle.read_batch()
            if len(recs):
                mlog.write_records(recs)
            if stats is not None:
                mlog.write_stats(stats.read_batch())
            if evs is not None:
                for ev in evs:
                    _write_event(mlog, ev, hist, recs, cycle.dropped)
            if len(recs):
                hist.add(recs)
            now = time.monotonic()
            dropped = cycle.dropped
            if dropped > reported_drops and (now - last_drop_report >= 1.0 or finished or stop_flag[0]):
                _log.warning("log writer fell behind: %d records dropped (%d new)",
                             dropped, dropped - reported_drops)
                t_ev = float(recs[-1][mlog.time_field]) if len(recs) and mlog.time_field else float("nan")
                mlog.write_event(t_ev, EventKind.DROPPED, "ring full, records dropped",
                                 dropped_total=dropped)
                reported_drops, last_drop_report = dropped, now
            mlog.tick(now)
            if finished and cycle.available() == 0:
                break
            if stop_flag[0]:
                why = "writer stopped by signal"
                if cycle.available() == 0:
                    break
                continue
            if not _alive(producer):
                why = f"producer pid {producer} died"
                evs = events.read_batch() if events is not None else None
                rest = cycle.read_batch()
                mlog.write_records(rest)
                for ev in evs if evs is not None else ():
                    _write_event(mlog, ev, hist, rest, cycle.dropped)
                mlog.write_event(float(rest[-1][mlog.time_field]) if len(rest) and mlog.time_field
                                 else float("nan"), EventKind.PRODUCER_LOST, why,
                                 dropped_total=cycle.dropped)
                break
            if not len(recs):
                time.sleep(poll_s)
    finally:
        _log.info("log writer closing (%s): %d records, %d dropped, files %s", why,
                  mlog.records_written, cycle.dropped, [str(p) for p in mlog.files])
        mlog.close()
    return mlog


def _write_metadata(mlog: McapLog, m: np.void) -> None:
    name = bytes(m["name"]).decode(errors="replace")
    try:
        values = json.loads(bytes(m["json"]).decode())
    except ValueError as exc:
        _log.error("metadata %r from the daemon is not JSON (%s); not written", name, exc)
        return
    mlog.add_metadata(name, {str(k): v if isinstance(v, str) else json.dumps(v) for k, v in values.items()})


def _write_event(mlog: McapLog, ev: np.void, hist: _History, batch: np.ndarray, dropped: int) -> None:
    kind = int(ev["kind"])
    try:
        kind = EventKind(kind)
    except ValueError:
        kind = EventKind.NOTICE
    reason = bytes(ev["reason"]).decode(errors="replace")
    last = None
    if kind == EventKind.FAULT:
        last = hist.last(int(ev["n_cycles"]), float(ev["t_s"]), mlog.time_field, batch)
        _log.error("fault at t=%.6f s: %s (code %#x), %d cycles attached", ev["t_s"], reason,
                   int(ev["code"]), len(last))
    mlog.write_event(float(ev["t_s"]), kind, reason, int(ev["code"]), dropped, last)


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
    :param float32_fields: float64 fields stored rounded to float32 (see
        :func:`capstan.controller.log.schema.build_layout`); never replay inputs or the command.
    :param zstd_level: zstd level of the chunks (1..22).
    :raises LogFormatError: if the dtype cannot be logged or a float32 field is invalid.
    :raises ValueError: on a zstd level out of 1..22.
    """

    def __init__(self, record_dtype: np.dtype, out_dir: str | Path, config_yaml: str = "",
                 stats_dtype: np.dtype | None = None, capacity: int = 8192, prefix: str = "capstan",
                 fault_history_n: int = 1000, flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
                 rotate_size_bytes: int = 0, rotate_time_s: float = 0.0,
                 compression: str = "zstd", float32_fields: tuple[str, ...] = (),
                 zstd_level: int = LIVE_ZSTD_LEVEL, drop_fields: tuple[str, ...] = ()) -> None:
        # fail here, not in the writer
        build_layout(stored_dtype(np.dtype(record_dtype), tuple(drop_fields)), "capstan.Cycle",
                     tuple(float32_fields))
        if not 1 <= int(zstd_level) <= 22:
            raise ValueError(f"zstd level must be 1..22, got {zstd_level}")
        self.out_dir = Path(out_dir)
        self.fault_history_n = fault_history_n
        self.cycle = LogRing.create(record_dtype, capacity, meta={"config_yaml": config_yaml})
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
                      "--drop-fields", ",".join(drop_fields)]
        self.proc: subprocess.Popen | None = None

    def start(self, ready_timeout_s: float = 10.0) -> None:
        """Spawn the writer process (``python -m capstan.controller.log.writer``) and wait until
        it has its signal handlers and first file open.

        :raises LogWriterError: if the writer exits or is not ready within ``ready_timeout_s``.
        """
        cmd = [sys.executable, "-m", "capstan.controller.log.writer", "--ring", self.cycle.name,
               "--events-ring", self.events.name, "--meta-ring", self.meta.name, "--out-dir", str(self.out_dir),
               "--parent-pid", str(os.getpid()), *self._args]
        if self.stats is not None:
            cmd += ["--stats-ring", self.stats.name]
        self.proc = subprocess.Popen(cmd)
        deadline = time.monotonic() + ready_timeout_s
        while not self.cycle.consumer_ready:
            if self.proc.poll() is not None:
                raise LogWriterError(f"log writer exited at start-up with code {self.proc.returncode}")
            if time.monotonic() > deadline:
                raise LogWriterError(f"log writer not ready after {ready_timeout_s} s")
            time.sleep(0.01)

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
        m = self._meta_rec
        m["name"], m["json"] = name.encode(), text
        return self.meta.push(m)

    @property
    def dropped(self) -> int:
        """Cycle records dropped so far."""
        return self.cycle.dropped

    def writer_alive(self) -> bool:
        """True while the writer process runs (check it about once a second)."""
        return self.proc is not None and self.proc.poll() is None

    def close(self, timeout_s: float = 10.0) -> int | None:
        """Close the rings, wait for the writer to finish the file; returns its exit code
        (None if it had to be killed after ``timeout_s``)."""
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
        for ring in (self.cycle, self.events, self.stats, self.meta):
            if ring is not None:
                ring.close()
        return code


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m capstan.controller.log.writer``; returns the exit code."""
    p = argparse.ArgumentParser(prog="python -m capstan.controller.log.writer", description=__doc__.split("\n")[0])
    p.add_argument("--ring", required=True, help="cycle ring file")
    p.add_argument("--events-ring", help="event ring file")
    p.add_argument("--stats-ring", help="stats ring file")
    p.add_argument("--meta-ring", help="metadata ring file")
    p.add_argument("--drop-fields", default="", help="comma-separated record fields not stored")
    p.add_argument("--out-dir", required=True)
    p.add_argument("--prefix", default="capstan")
    p.add_argument("--rotate-size-bytes", type=int, default=0)
    p.add_argument("--rotate-time-s", type=float, default=0.0)
    p.add_argument("--flush-interval-s", type=float, default=DEFAULT_FLUSH_INTERVAL_S)
    p.add_argument("--compression", default="zstd", choices=("zstd", "lz4", "none"))
    p.add_argument("--fault-history", type=int, default=1000)
    p.add_argument("--parent-pid", type=int, default=0)
    p.add_argument("--float32-fields", default="", help="comma-separated fields stored as float32")
    p.add_argument("--zstd-level", type=int, default=LIVE_ZSTD_LEVEL, help="zstd level of the chunks")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(levelname)s log_writer: %(message)s")
    stop = [False]

    def _on_term(signum: int, frame: object) -> None:
        stop[0] = True

    signal.signal(signal.SIGTERM, _on_term)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    cycle = LogRing.attach(args.ring)
    events = LogRing.attach(args.events_ring) if args.events_ring else None
    stats = LogRing.attach(args.stats_ring) if args.stats_ring else None
    meta = LogRing.attach(args.meta_ring) if args.meta_ring else None
    run_writer(cycle, args.out_dir, events, stats, args.prefix, args.rotate_size_bytes,
               args.rotate_time_s, args.flush_interval_s, args.compression, args.fault_history,
               parent_pid=args.parent_pid, stop_flag=stop,
               float32_fields=tuple(f for f in args.float32_fields.split(",") if f),
               zstd_level=args.zstd_level, meta=meta,
               drop_fields=tuple(f for f in args.drop_fields.split(",") if f))
    orphaned = not _alive(args.parent_pid or cycle.producer_pid)
    for ring in (cycle, events, stats, meta):
        if ring is not None:
            ring.close(unlink=orphaned)     # the producer cannot clean up after itself
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
