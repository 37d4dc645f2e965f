"""An MCAP log file set: cycle records (protobuf), events (JSON), stats, config metadata,
chunk flushing on a time budget and rotation by size and time.

Used by the writer process (:mod:`capstan.controller.log.writer`) and offline by replay to write
what-if logs. Each file of a rotated set is complete on its own: header, the daemon
config as a ``capstan.config`` metadata record, the ``capstan.log`` metadata record
(numpy dtype, topics, file index), schemas and channels, then chunks.

Message indexes, chunk indexes and the summary are written, so seeking readers and
Foxglove work (Foxglove's indexed reader refuses chunk indexes without message indexes),
and a file cut off by a kill is read by streaming. The file itself is written by
:class:`capstan.controller.log.mcap_writer.McapChunkWriter` (a whole batch of records becomes message
records and index entries in one numpy operation; zstd at a chosen level).

Size: one message per cycle (Foxglove plots each field against time). What a cycle
costs on disk is dominated by the noisy float64 fields (about 4 to 8 bytes each after
zstd) and the 16 uncompressed bytes of its message-index entry; ``float32_fields``
stores fields that need no more (see :data:`capstan.controller.law.records.LOG_FLOAT32_FIELDS`) as
protobuf ``float``.
"""

from __future__ import annotations

import enum
import json
import logging
import math
import os
import socket
import time
from pathlib import Path
from collections.abc import Mapping
from typing import Any

import numpy as np

from capstan.controller.log.ring import dtype_to_json
from capstan.controller.log.schema import (MESSAGE_ENCODING, SCHEMA_ENCODING, LogFormatError, ProtoLayout,
                                           build_layout, event_schema_bytes)
from capstan.controller.log.mcap_writer import DEFAULT_ZSTD_LEVEL, McapChunkWriter

_log = logging.getLogger(__name__)

CYCLE_TOPIC = "/capstan/cycle"
EVENTS_TOPIC = "/capstan/events"
STATS_TOPIC = "/capstan/stats"
#: metadata record naming how the SI fields follow from the stored wire fields
DERIVATIONS_META = "capstan.derivations"
LOG_FORMAT_VERSION = "1"
#: default chunk close period [s]: a kill of the writer loses at most this, plus one
#: poll (5 ms) and the compression of one chunk (~30 ms at the live writer's zstd level), so
#: well inside the 1 s the daemon promises; longer chunks compress a little better
DEFAULT_FLUSH_INTERVAL_S = 0.8


class EventKind(enum.IntEnum):
    """Kinds of ``/capstan/events`` messages."""

    FAULT = 1            #: the loop latched a fault; the last N cycles are attached
    DROPPED = 2          #: records were dropped because the writer fell behind
    NOTICE = 3           #: informational (start, rotation, shutdown reason)
    PRODUCER_LOST = 4    #: the daemon died without closing the ring
    WRITER_RESTARTED = 5  #: first event of a file after the previous writer died: the gap


def _json_value(x: Any) -> Any:
    """Plain JSON value; non-finite floats become the strings "nan", "inf", "-inf"."""
    if isinstance(x, float) and not math.isfinite(x):
        return "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf")
    return x


def columns_to_json(records: np.ndarray) -> dict[str, list]:
    """Records as ``{field: [values]}`` with JSON-safe values."""
    return {n: [_json_value(v) for v in records[n].tolist()] for n in records.dtype.names}


def stored_dtype(record_dtype: np.dtype, drop_fields: tuple[str, ...] = ()) -> np.dtype:
    """The record dtype without ``drop_fields`` (what a live log stores per cycle).

    :raises LogFormatError: if a dropped field is not in the record.
    """
    names = record_dtype.names or ()
    unknown = [f for f in drop_fields if f not in names]
    if unknown:
        raise LogFormatError(f"dropped fields {unknown} are not fields of the record")
    return np.dtype([(n, record_dtype[n]) for n in names if n not in drop_fields])


class McapLog:
    """Writes records to a rotating set of MCAP files.

    :param out_dir: directory for the files (created).
    :param prefix: file name prefix; files are ``{prefix}_{YYYYmmdd-HHMMSS}_{index:03d}.mcap``.
    :param record_dtype: dtype of the cycle records (must contain ``time_field`` for
        message times; otherwise the wall clock at writing is used).
    :param config_yaml: the daemon config as YAML text (stored in every file).
    :param stats_dtype: dtype of ``/capstan/stats`` records, or None for no stats channel.
    :param rotate_size_bytes: start a new file once a file reaches this size (0 = never).
    :param rotate_time_s: start a new file after this long (0 = never).
    :param flush_interval_s: close the open chunk and flush the file at least this often
        (bounds what a kill of the writer loses); 0 = only on chunk size.
    :param compression: ``"zstd"``, ``"lz4"`` or ``"none"``.
    :param zstd_level: zstd level of the chunks (1..22; higher = smaller and slower).
    :param chunk_size_bytes: close a chunk at this uncompressed size in any case.
    :param extra_meta: more key -> text pairs for the ``capstan.log`` metadata record.
    :param float32_fields: float64 record fields stored rounded to float32 (smaller
        files; only for fields replay recomputes).
    :param float32_quanta: float32 field -> power-of-two quantum it is rounded to
        before the float32 cast (display copies of values replay recomputes; see
        :func:`capstan.controller.log.schema.quantize_float32`); recorded in the cycle
        channel's ``float32_quanta`` metadata.
    :param first_path: exact path of the first file (offline what-if logs); later
        rotated files follow the naming pattern.
    :param keep_bytes: retention: after each new file is opened, the oldest
        ``{prefix}_*.mcap`` files of ``out_dir`` are deleted until the others (the open one
        included) take at most this many bytes (0 = keep everything).
    :param drop_fields: record fields not stored (SI values a reader rebuilds from the
        stored wire values with the ``capstan.derivations`` metadata, see
        :meth:`add_metadata`); the full record dtype goes in the channel metadata.
    :raises ValueError: on an unknown compression or a zstd level out of 1..22.
    :raises LogFormatError: if a dtype cannot be logged.
    """

    def __init__(self, out_dir: str | Path, prefix: str, record_dtype: np.dtype, config_yaml: str = "",
                 stats_dtype: np.dtype | None = None, rotate_size_bytes: int = 0,
                 rotate_time_s: float = 0.0, flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
                 compression: str = "zstd", chunk_size_bytes: int = 1 << 20,
                 time_field: str = "t_s", extra_meta: dict[str, str] | None = None,
                 first_path: str | Path | None = None, float32_fields: tuple[str, ...] = (),
                 zstd_level: int = DEFAULT_ZSTD_LEVEL, drop_fields: tuple[str, ...] = (),
                 keep_bytes: int = 0, float32_quanta: Mapping[str, float] | None = None) -> None:
        comp = {"zstd": "zstd", "lz4": "lz4", "none": ""}
        if compression not in comp:
            raise ValueError(f"compression must be one of {', '.join(comp)}, got {compression!r}")
        if compression == "zstd" and not 1 <= int(zstd_level) <= 22:
            raise ValueError(f"zstd level must be 1..22, got {zstd_level}")
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.prefix = prefix
        self.record_dtype = np.dtype(record_dtype)
        self.drop_fields = tuple(drop_fields)
        self.layout: ProtoLayout = build_layout(stored_dtype(self.record_dtype, self.drop_fields),
                                                "capstan.Cycle", tuple(float32_fields), float32_quanta)
        self._metadata: dict[str, dict[str, str]] = {}
        self.stats_layout = build_layout(stats_dtype, "capstan.Stats") if stats_dtype is not None else None
        self.config_yaml = config_yaml
        self.float32_fields = tuple(float32_fields)
        self.rotate_size_bytes = int(rotate_size_bytes)
        self.rotate_time_s = float(rotate_time_s)
        self.flush_interval_s = float(flush_interval_s)
        self.chunk_size_bytes = int(chunk_size_bytes)
        self.time_field = time_field if time_field in (record_dtype.names or ()) else ""
        self.extra_meta = dict(extra_meta or {})
        self._compression = comp[compression]
        self.zstd_level = int(zstd_level)
        self.files: list[Path] = []
        self.records_written = 0
        #: records handed to the OS at the last flush, and the ``cycle`` of the last of them
        self.records_flushed = 0
        self.last_flushed_cycle = -1
        self._last_cycle = -1
        self._fh: Any = None
        self._writer: McapChunkWriter | None = None
        self._opened_at = 0.0
        self._last_flush = 0.0
        self._last_t_ns = 0
        self._first_path = Path(first_path) if first_path is not None else None
        self.keep_bytes = int(keep_bytes)
        #: files deleted by the retention policy
        self.deleted: list[Path] = []
        self._open_next()
        self.apply_retention()

    # ------------------------------------------------------------------ files
    def _open_next(self) -> None:
        stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
        index = len(self.files)
        path = self.out_dir / f"{self.prefix}_{stamp}_{index:03d}.mcap"
        while path.exists() and self._first_path is None:   # a restarted writer in the same second
            index += 1
            path = self.out_dir / f"{self.prefix}_{stamp}_{index:03d}.mcap"
        if self._first_path is not None and not self.files:
            path = self._first_path
            path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(path, "wb")
        w = McapChunkWriter(self._fh, self._compression, self.zstd_level, self.chunk_size_bytes)
        w.start(library="capstan")
        w.add_metadata("capstan.config", {"yaml": self.config_yaml})
        meta = {"format_version": LOG_FORMAT_VERSION, "record_topic": CYCLE_TOPIC,
                "numpy_dtype": json.dumps(dtype_to_json(self.layout.dtype)),
                "time_field": self.time_field, "file_index": str(len(self.files)),
                "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "host": socket.gethostname(),
                "wall_minus_monotonic_s": repr(time.time() - time.monotonic())}
        meta.update(self.extra_meta)
        w.add_metadata("capstan.log", meta)
        sid = w.register_schema(self.layout.message_name, SCHEMA_ENCODING, self.layout.schema)
        ch_meta = {"numpy_dtype": meta["numpy_dtype"], "float32_fields": json.dumps(list(self.float32_fields))}
        if self.layout.quanta:
            ch_meta["float32_quanta"] = json.dumps(dict(self.layout.quanta))
        if self.drop_fields:
            ch_meta["record_dtype"] = json.dumps(dtype_to_json(self.record_dtype))
            ch_meta["derived_fields"] = json.dumps(list(self.drop_fields))
        self._cycle_ch = w.register_channel(CYCLE_TOPIC, MESSAGE_ENCODING, sid, ch_meta)
        for name, values in self._metadata.items():
            w.add_metadata(name, values)
        eid = w.register_schema("capstan.Event", "jsonschema", event_schema_bytes())
        self._event_ch = w.register_channel(EVENTS_TOPIC, "json", eid)
        self._stats_ch = 0
        if self.stats_layout is not None:
            tid = w.register_schema(self.stats_layout.message_name, SCHEMA_ENCODING, self.stats_layout.schema)
            self._stats_ch = w.register_channel(
                STATS_TOPIC, MESSAGE_ENCODING, tid,
                {"numpy_dtype": json.dumps(dtype_to_json(self.stats_layout.dtype))})
        w.flush()
        self._writer = w
        self.files.append(path)
        self._opened_at = self._last_flush = time.monotonic()
        _log.info("logging to %s", path)

    def _finish_file(self) -> None:
        if self._writer is not None:
            self._writer.finish()
            self._fh.flush()
            os.fsync(self._fh.fileno())
            self._fh.close()
            self._writer = None
            self.records_flushed, self.last_flushed_cycle = self.records_written, self._last_cycle

    @property
    def current_file(self) -> Path:
        """The file being written."""
        return self.files[-1]

    # ------------------------------------------------------------------ writing
    def _times_ns(self, records: np.ndarray, field: str) -> np.ndarray:
        """Log times [ns] from ``field`` [s] (non-finite or negative -> 0), else the wall clock."""
        if field:
            t = np.nan_to_num(records[field].astype(np.float64) * 1e9, nan=0.0, posinf=0.0, neginf=0.0)
            return np.round(t).clip(0, 2.0**63 - 1024).astype(np.int64)
        return np.full(len(records), time.time_ns(), np.int64)

    def write_records(self, records: np.ndarray) -> None:
        """Append cycle records (protobuf messages on ``/capstan/cycle``)."""
        if not len(records):
            return
        self._add(self._cycle_ch, self.layout, records, self.time_field)
        self.records_written += len(records)
        if "cycle" in (records.dtype.names or ()):
            self._last_cycle = int(records["cycle"][-1])

    def write_stats(self, records: np.ndarray) -> None:
        """Append ``/capstan/stats`` records (ignored without a stats dtype)."""
        if self.stats_layout is None or not len(records):
            return
        tf = "t_s" if "t_s" in (records.dtype.names or ()) else ""
        self._add(self._stats_ch, self.stats_layout, records, tf)

    def _add(self, channel: int, layout: ProtoLayout, records: np.ndarray, time_field: str) -> None:
        w = self._writer
        assert w is not None
        times = self._times_ns(records, time_field)
        w.add_messages(channel, times, layout.encode(records))
        if channel == self._cycle_ch:
            self._last_t_ns = int(times[-1])

    def add_metadata(self, name: str, values: dict[str, str]) -> None:
        """Write a metadata record now and into every later file of the set (rotation)."""
        assert self._writer is not None
        self._metadata[name] = dict(values)
        self._writer.add_metadata(name, dict(values))
        self.flush()

    def write_event(self, t_s: float, kind: EventKind, reason: str = "", code: int = 0,
                    dropped_total: int = 0, last_cycles: np.ndarray | None = None,
                    extra: dict[str, Any] | None = None) -> None:
        """Append one JSON event on ``/capstan/events`` and flush it to disk at once.

        :param extra: more JSON members (e.g. the ``gap_*`` members of WRITER_RESTARTED).
        """
        assert self._writer is not None
        msg: dict[str, Any] = {"t_s": _json_value(float(t_s)), "kind": int(kind),
                               "kind_name": EventKind(kind).name, "code": int(code),
                               "reason": reason, "dropped_total": int(dropped_total)}
        if extra:
            msg.update(extra)
        if last_cycles is not None:
            msg["last_cycles"] = columns_to_json(last_cycles)
        # an event without its own time is placed at the last cycle's time, on the same
        # (monotonic) time axis as the records
        t_ns = max(0, int(round(t_s * 1e9))) if math.isfinite(t_s) else self._last_t_ns
        self._writer.add_message(self._event_ch, t_ns, json.dumps(msg).encode())
        self.flush()

    # ------------------------------------------------------------------ policy
    def flush(self) -> None:
        """Close the open chunk and hand everything to the OS."""
        if self._writer is not None:
            self._writer.flush()
            self._last_flush = time.monotonic()
            self.records_flushed, self.last_flushed_cycle = self.records_written, self._last_cycle

    def tick(self, now: float | None = None) -> None:
        """Apply the flush and rotation policies; call after each batch."""
        now = time.monotonic() if now is None else now
        if self.flush_interval_s > 0 and now - self._last_flush >= self.flush_interval_s:
            self.flush()
        rotate = self.rotate_time_s > 0 and now - self._opened_at >= self.rotate_time_s
        if self.rotate_size_bytes > 0 and self._writer is not None \
                and self._writer.tell() >= self.rotate_size_bytes:
            rotate = True
        if rotate:
            self._finish_file()
            self._open_next()
            self.apply_retention()

    def apply_retention(self) -> list[Path]:
        """Delete the oldest ``{prefix}_*.mcap`` files (never the open one) while the set
        takes more than ``keep_bytes``; each deletion is logged and written as a NOTICE
        event into the open file. Returns the files deleted now."""
        if self.keep_bytes <= 0:
            return []
        # names carry the UTC start time and the index: name order is age order (a file
        # rewritten by recovery keeps its name, not its modification time)
        files = sorted(self.out_dir.glob(f"{self.prefix}_*.mcap"), key=lambda f: f.name)
        total = sum(f.stat().st_size for f in files)
        gone: list[Path] = []
        for f in files:
            if total <= self.keep_bytes or f == self.current_file:
                break
            size = f.stat().st_size
            try:
                f.unlink()
            except OSError as exc:
                _log.error("retention: cannot delete %s: %s", f, exc)
                continue
            total -= size
            gone.append(f)
            _log.info("retention: deleted %s (%d bytes; keeping the newest %d bytes)", f, size, self.keep_bytes)
            self.write_event(float("nan"), EventKind.NOTICE, f"retention: deleted {f.name} ({size} bytes)")
        self.deleted += gone
        return gone

    def close(self) -> None:
        """Finish the current file (summary, footer) and close it. Idempotent."""
        self._finish_file()
