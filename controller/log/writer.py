"""The log writer process: drains the shared-memory rings and writes MCAP.

Producer side (the daemon): :class:`capstan.controller.log.session.LogSession` (re-exported
here), which also supervises this process and restarts it into a new file.

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
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from capstan.controller.log.ring import LogRing, pid_alive
from capstan.controller.log.session import (EVENT_DTYPE, LIVE_ZSTD_LEVEL, META_DTYPE,  # noqa: F401 (re-exported)
                                            LogSession, LogWriterError)
from capstan.controller.log.mcap_log import DEFAULT_FLUSH_INTERVAL_S, EventKind, McapLog, stored_dtype
from capstan.controller.log.schema import LogFormatError, build_layout
from capstan.models.common.errors import DataFormatError

_log = logging.getLogger(__name__)

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


def run_writer(cycle: LogRing, out_dir: str | Path, events: LogRing | None = None,
               stats: LogRing | None = None, prefix: str = "capstan", rotate_size_bytes: int = 0,
               rotate_time_s: float = 0.0, flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
               compression: str = "zstd", fault_history_n: int = 1000, poll_s: float = 0.005,
               parent_pid: int = 0, stop_flag: list[bool] | None = None,
               float32_fields: tuple[str, ...] = (), zstd_level: int = LIVE_ZSTD_LEVEL,
               meta: LogRing | None = None, drop_fields: tuple[str, ...] = (),
               gap_after_cycle: int | None = None, gap_reason: str = "", keep_bytes: int = 0,
               float32_quanta: dict[str, float] | None = None) -> McapLog:
    """Drain the rings into MCAP until the producer closes, dies, or ``stop_flag[0]``.

    :param gap_after_cycle: this writer replaces a dead one whose last record on disk had
        this cycle number (-1: none): a WRITER_RESTARTED event naming the missing cycles
        precedes the first record (``gap_reason`` says why).
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
                   float32_fields=float32_fields, zstd_level=zstd_level, drop_fields=drop_fields,
                   keep_bytes=keep_bytes, float32_quanta=float32_quanta,
                   extra_meta={str(k): str(v) for k, v in dict(cycle.meta.get("log_meta", {})).items()})
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
            if gap_after_cycle is not None and (len(recs) or finished):
                _write_gap(mlog, recs, gap_after_cycle, gap_reason, cycle.dropped)
                gap_after_cycle = None
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
            cycle.set_durable(mlog.records_flushed, mlog.last_flushed_cycle)
            if finished and cycle.available() == 0:
                break
            if stop_flag[0]:
                why = "writer stopped by signal"
                if cycle.available() == 0:
                    break
                continue
            if not pid_alive(producer):
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


def _write_gap(mlog: McapLog, recs: np.ndarray, after: int, reason: str, dropped: int) -> None:
    """The WRITER_RESTARTED event: cycles ``after + 1`` up to the first one read now are missing."""
    if len(recs) and "cycle" in (recs.dtype.names or ()):
        first = int(recs["cycle"][0])
        t = float(recs[0][mlog.time_field]) if mlog.time_field else float("nan")
        gap = {"gap_cycles": first - after - 1, "gap_first_cycle": after + 1, "gap_last_cycle": first - 1}
        text = f"{reason}; cycles {after + 1}..{first - 1} ({first - after - 1}) are missing"
    else:
        t, gap, text = float("nan"), {}, f"{reason}; no record followed"
    _log.error("writer restarted: %s", text)
    mlog.write_event(t, EventKind.WRITER_RESTARTED, text, gap.get("gap_cycles", 0), dropped, extra=gap)


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


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m capstan.controller.log.writer``; returns the exit code."""
    p = argparse.ArgumentParser(prog="python -m capstan.controller.log.writer", description=__doc__.split("\n")[0])
    p.add_argument("--ring", required=True, help="cycle ring file")
    p.add_argument("--events-ring", help="event ring file")
    p.add_argument("--stats-ring", help="stats ring file")
    p.add_argument("--meta-ring", help="metadata ring file")
    p.add_argument("--drop-fields", default="", help="comma-separated record fields not stored")
    p.add_argument("--gap-after-cycle", type=int, default=None,
                   help="replacing a dead writer: its last cycle on disk (-1 none)")
    p.add_argument("--gap-reason", default="previous log writer died")
    p.add_argument("--keep-bytes", type=int, default=0, help="retention: keep the newest files up to this size")
    p.add_argument("--recover", help="first rewrite this log, cut off by a dead writer, into a valid file")
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
    p.add_argument("--float32-quanta", default="{}",
                   help="JSON object: float32 field -> power-of-two quantum it is stored rounded to")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(levelname)s log_writer: %(message)s")
    stop = [False]

    def _on_term(signum: int, frame: object) -> None:
        stop[0] = True

    signal.signal(signal.SIGTERM, _on_term)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if args.recover:
        from capstan.controller.log.recover import recover_log
        try:
            recover_log(args.recover)
        except (DataFormatError, OSError) as exc:
            _log.error("could not recover %s: %s", args.recover, exc)
    cycle = LogRing.attach(args.ring)
    events = LogRing.attach(args.events_ring) if args.events_ring else None
    stats = LogRing.attach(args.stats_ring) if args.stats_ring else None
    meta = LogRing.attach(args.meta_ring) if args.meta_ring else None
    run_writer(cycle, args.out_dir, events, stats, args.prefix, args.rotate_size_bytes,
               args.rotate_time_s, args.flush_interval_s, args.compression, args.fault_history,
               parent_pid=args.parent_pid, stop_flag=stop,
               float32_fields=tuple(f for f in args.float32_fields.split(",") if f),
               zstd_level=args.zstd_level, meta=meta,
               drop_fields=tuple(f for f in args.drop_fields.split(",") if f),
               gap_after_cycle=args.gap_after_cycle, gap_reason=args.gap_reason, keep_bytes=args.keep_bytes,
               float32_quanta=json.loads(args.float32_quanta))
    orphaned = not pid_alive(args.parent_pid or cycle.producer_pid)
    for ring in (cycle, events, stats, meta):
        if ring is not None:
            ring.close(unlink=orphaned)     # the producer cannot clean up after itself
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
