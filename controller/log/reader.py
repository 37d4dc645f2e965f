"""Read a capstan MCAP log back: cycle records as a structured array, the stored config,
the log metadata, events and stats.

Reads by streaming (no summary needed), so a file whose writer was killed is read up
to its last complete chunk and flagged ``truncated``. Cycle messages are collected
per chunk with a small record walker and decoded in one vectorised step.
"""

from __future__ import annotations

import io
import json
import logging
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import lz4.frame
import numpy as np
import yaml
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, Footer, Message, McapRecord, Metadata, Schema
from mcap.reader import SeekingReader
from mcap.stream_reader import StreamReader

from capstan.controller.log.ring import dtype_from_json
from capstan.controller.log.mcap_log import CYCLE_TOPIC, DERIVATIONS_META, EVENTS_TOPIC, STATS_TOPIC
from capstan.controller.log.schema import ProtoLayout, build_layout
from capstan.controller.log import record_bytes, wire_decode
from capstan.models.common.errors import DataFormatError
from capstan.models.common.wire_units import Derivation, apply_ops

_log = logging.getLogger(__name__)

_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE = 0x03, 0x04, 0x05
_MSG_HEAD = 22  # channel u16, sequence u32, log_time u64, publish_time u64


@dataclass
class LogData:
    """Contents of one capstan log file.

    :ivar path: the file.
    :ivar records: cycle records (structured array of the logged dtype).
    :ivar config_yaml: the daemon config as stored (YAML text, may be empty).
    :ivar config: ``config_yaml`` parsed (empty dict if none).
    :ivar meta: the ``capstan.log`` metadata record (dtype, topics, file index, host...).
    :ivar events: decoded ``/capstan/events`` messages (dicts), in file order.
    :ivar stats: ``/capstan/stats`` records, or None if the log has none.
    :ivar truncated: True if the file ends without a footer (writer killed); everything
        up to the last complete chunk is in ``records``.
    """

    path: Path
    records: np.ndarray
    config_yaml: str = ""
    config: dict[str, Any] = field(default_factory=dict)
    meta: dict[str, str] = field(default_factory=dict)
    events: list[dict[str, Any]] = field(default_factory=list)
    stats: np.ndarray | None = None
    truncated: bool = False

    def event_cycles(self, event: dict[str, Any]) -> np.ndarray:
        """The ``last_cycles`` attached to a fault event, as records of the log's dtype."""
        cols = event.get("last_cycles") or {}
        n = len(next(iter(cols.values()))) if cols else 0
        out = np.zeros(n, self.records.dtype)
        for name, values in cols.items():
            if name in (out.dtype.names or ()):
                out[name] = [float(v) if isinstance(v, str) else v for v in values]
        return out


class _Collector:
    """Gathers records while streaming; protobuf channels with a numpy dtype are
    decoded chunk by chunk (small, cache-friendly arrays), others kept as raw messages."""

    def __init__(self, counts: dict[int, int] | None = None, fields: tuple[str, ...] | None = None,
                 derivations_json: str | None = None) -> None:
        #: channel -> message count from the file's summary (preallocated decoding)
        self.counts = dict(counts or {})
        #: cycle fields to decode (None: all); derived ones need the derivations up front
        self.fields = fields
        self.derivations = _parse_derivations(derivations_json)
        self.sources = {d.field: d.source for d in self.derivations}
        #: rebuilt in the compiled pass: cycle channel -> derived field names
        self.derived: tuple[str, ...] = ()
        #: cycle rows decoded by the numpy path (SI fields rebuilt after reading)
        self.slow_rows: list[tuple[int, int]] = []
        #: channel -> [preallocated records, records filled]
        self.buffers: dict[int, list[Any]] = {}
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.payloads: dict[int, list[Any]] = {}
        self.layouts: dict[int, ProtoLayout] = {}
        #: channel -> full record dtype to decode into (a live log storing wire values)
        self.full: dict[int, np.dtype] = {}
        self.metadata: dict[str, dict[str, str]] = {}
        self.zstd: zstandard.ZstdDecompressor | None = None
        #: the cycle channel decoded by the compiled path: (channel id, field table)
        self.fast: tuple[int, wire_decode.FieldTable] | None = None

    def channel(self, ch: Channel) -> None:
        self.channels[ch.id] = ch
        self.payloads.setdefault(ch.id, [])
        descr = ch.metadata.get("numpy_dtype") or (
            self.metadata.get("capstan.log", {}).get("numpy_dtype") if ch.topic == CYCLE_TOPIC else None)
        if ch.message_encoding == "protobuf" and descr:
            schema = self.schemas.get(ch.schema_id)
            f32 = tuple(json.loads(ch.metadata.get("float32_fields", "[]")))
            layout = build_layout(dtype_from_json(json.loads(descr)),
                                  schema.name if schema is not None else "capstan.Cycle", f32)
            if schema is not None and schema.data != layout.schema:
                raise DataFormatError(f"schema of {ch.topic} does not match its numpy dtype")
            self.layouts[ch.id] = layout
            if "record_dtype" in ch.metadata:
                self.full[ch.id] = dtype_from_json(json.loads(ch.metadata["record_dtype"]))
            if ch.topic == CYCLE_TOPIC and self.fields is not None:
                self.full[ch.id] = self.subset(self.full.get(ch.id, layout.dtype), layout.dtype.names)
            target = self.full.get(ch.id, layout.dtype)
            if ch.topic == CYCLE_TOPIC and self.fast is None and wire_decode.supported(target):
                missing = tuple(n for n in target.names if n not in layout.dtype.names)
                derive = record_bytes.NO_DERIVATIONS
                if missing and all(self.sources.get(n) in layout.dtype.names for n in missing) \
                        and all(target.fields[n][0] == np.float64 for n in missing):
                    derive = record_bytes.derive_table(target, self.derivations, missing)
                    self.derived = missing
                table = wire_decode.field_table(layout, target)
                self.fast = (ch.id, table, wire_decode.kernel_derive(table, derive))

    def add(self, ch: int, blob: Any) -> None:
        layout = self.layouts.get(ch)
        if layout is None:
            self.payloads[ch].append(blob)
            return
        raw = np.frombuffer(blob, dtype=np.uint8) if not isinstance(blob, np.ndarray) else blob.reshape(-1)
        if raw.size % layout.message_size:
            raise DataFormatError(f"{layout.message_name}: {raw.size} bytes is not a multiple of the "
                                  f"message size {layout.message_size}")
        self.store(ch, raw, 0, raw.size // layout.message_size, layout.message_size)

    def subset(self, full: np.dtype, stored: tuple[str, ...]) -> np.dtype:
        """``full`` restricted to the requested fields and the wire fields they are
        rebuilt from (all of ``full`` if a requested field's source is unknown)."""
        assert self.fields is not None
        keep = set(self.fields) & set(full.names)
        for name in list(keep):
            if name not in stored:
                if name not in self.sources:
                    return full
                keep.add(self.sources[name])
        return np.dtype([(n, full[n]) for n in full.names if n in keep])

    def room(self, ch: int, n: int) -> np.ndarray:
        """The preallocated records of channel ``ch`` (sized from the summary's count),
        grown so that ``n`` more fit."""
        dtype = self.full.get(ch, self.layouts[ch].dtype)
        buf = self.buffers.get(ch)
        if buf is None:
            buf = self.buffers[ch] = [np.empty(max(self.counts.get(ch, 0), n), dtype), 0]
        elif buf[1] + n > len(buf[0]):          # no summary, or its count was short
            grown = np.empty(max(2 * len(buf[0]), buf[1] + n), dtype)
            grown[:buf[1]] = buf[0][:buf[1]]
            buf[0] = grown
        return buf[0]

    def store(self, ch: int, buf: np.ndarray, offset: int, n: int, stride: int) -> None:
        """Decode ``n`` messages of channel ``ch`` at ``buf[offset + k * stride]`` into its
        preallocated array."""
        layout = self.layouts[ch]
        out = self.room(ch, n)
        filled = self.buffers[ch][1]
        layout.decode_span(buf, offset, n, stride, out.dtype, out=out[filled:filled + n])
        self.buffers[ch][1] += n
        if self.fast is not None and ch == self.fast[0]:
            self.slow_rows.append((filled, filled + n))

    def decode_fast(self, buf: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Decode the cycle messages of a chunk's bytes with the compiled path; returns
        (opcode, body, length) of every other record.

        :raises DataFormatError: if a cycle message is not valid protobuf or a field has
            a wire type other than its schema's.
        """
        assert self.fast is not None
        ch, table, derive = self.fast
        others = np.empty((buf.size // 9 + 1, 3), np.int64)
        seen = np.zeros(table.wire_type.size, np.int64)
        est = buf.size // (self.layouts[ch].message_size + _MSG_HEAD + 9) + 1
        pos, n_other = 0, 0
        need = est if ch not in self.buffers and not self.counts.get(ch) else 0
        while True:
            out = self.room(ch, need)
            rows = out.view(np.uint8).reshape(len(out), out.dtype.itemsize)
            status, pos, n, k, detail = wire_decode.decode(buf, pos, ch, rows, self.buffers[ch][1], table,
                                                           derive, others[n_other:], seen)
            self.buffers[ch][1] += n
            n_other += k
            if status == wire_decode.OK:
                break
            need = est
            wire_decode.raise_for_status(status, detail, table, self.channels[ch].topic, self.buffers[ch][1], pos)
        o = others[:n_other]
        return o[:, 0].astype(np.uint8), o[:, 1], o[:, 2]

    def walk_chunk(self, chunk: Chunk) -> None:
        if chunk.compression == "zstd":
            if self.zstd is None:                # one context for the file (not one per chunk)
                self.zstd = zstandard.ZstdDecompressor()
            data = self.zstd.decompress(chunk.data, max_output_size=chunk.uncompressed_size)
        elif chunk.compression == "lz4":
            data = lz4.frame.decompress(chunk.data)
        elif chunk.compression == "":
            data = chunk.data
        else:
            raise DataFormatError(f"unsupported chunk compression {chunk.compression!r}")
        buf = np.frombuffer(data, dtype=np.uint8)
        if self.fast is not None:
            ops, bodies, lengths = self.decode_fast(buf)
        else:
            ops, bodies, lengths = _scan_records(buf)
        is_msg = ops == _OP_MESSAGE
        # schemas and channels first: a chunk may define a channel and carry its messages
        for op, body, length in zip(ops[~is_msg].tolist(), bodies[~is_msg].tolist(),
                                     lengths[~is_msg].tolist()):
            if op == _OP_SCHEMA:
                sch = Schema.read(ReadDataStream(io.BytesIO(data[body:body + length])))
                self.schemas[sch.id] = sch
            elif op == _OP_CHANNEL:
                self.channel(Channel.read(ReadDataStream(io.BytesIO(data[body:body + length]))))
        if is_msg.any():
            m_body, m_len = bodies[is_msg], lengths[is_msg]
            chans = buf[m_body].astype(np.int64) | (buf[m_body + 1].astype(np.int64) << 8)
            for ch in np.unique(chans):
                lst = self.payloads.get(int(ch))
                if lst is None:
                    continue
                sel = chans == ch
                start, size = m_body[sel] + _MSG_HEAD, m_len[sel] - _MSG_HEAD
                fixed = self.channels[int(ch)].message_encoding == "protobuf" and np.all(size == size[0])
                if fixed and int(ch) in self.layouts:
                    # fixed-size messages: each run of evenly spaced ones (other channels'
                    # messages break runs) decoded from the chunk in place
                    stride = int(size[0]) + _MSG_HEAD + 9
                    cuts = np.r_[0, np.flatnonzero(np.diff(start) != stride) + 1, len(start)]
                    for a, b in zip(cuts[:-1].tolist(), cuts[1:].tolist()):
                        self.store(int(ch), buf, int(start[a]), b - a, stride if b - a > 1 else int(size[0]))
                elif fixed:                      # fixed-size messages: one blob
                    self.add(int(ch), _gather(buf, start, int(size[0])))
                elif int(ch) in self.layouts:
                    self.add(int(ch), b"".join(data[a:a + b] for a, b in zip(start.tolist(), size.tolist())))
                else:
                    lst.extend(data[a:a + b] for a, b in zip(start.tolist(), size.tolist()))


class _RecordReader(StreamReader):
    """The ``mcap`` streaming reader, passing over MessageIndex records unparsed: this
    module finds messages by walking chunks, and ``MessageIndex.read`` builds a Python
    tuple per indexed message (about a third of the time to read a log)."""

    def _read_record(self, opcode: int, length: int) -> McapRecord | None:
        stream = getattr(self, "_stream", None)
        if opcode == Opcode.MESSAGE_INDEX and stream is not None:
            stream.read(length)
            return None
        return super()._read_record(opcode, length)


def _gather(buf: np.ndarray, start: np.ndarray, size: int) -> bytes:
    """Concatenate ``buf[start[i]:start[i]+size]``; a strided view when evenly spaced."""
    n = len(start)
    stride = int(start[1] - start[0]) if n > 1 else size
    if stride >= size and (n == 1 or np.all(np.diff(start) == stride)) \
            and int(start[0]) + (n - 1) * stride + size <= buf.size:
        rows = np.lib.stride_tricks.as_strided(buf[int(start[0]):], shape=(n, size), strides=(stride, 1))
        return rows.tobytes()
    return buf[start[:, None] + np.arange(size)[None, :]].tobytes()


def _scan_records(buf: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(opcode, body offset, body length) of every complete record in a chunk's bytes.

    Runs of records with an identical 9-byte header (same opcode and length, i.e. the
    fixed-size cycle messages) are found with one vectorised comparison per run.
    """
    ops, bodies, lengths = [], [], []
    pos, end = 0, buf.size
    while pos + 9 <= end:
        length = int.from_bytes(buf[pos + 1:pos + 9].tobytes(), "little")
        size = 9 + length
        if pos + size > end:
            break
        n_max = min((end - pos) // size, 8192)
        k = 1
        if n_max > 1:
            heads = np.lib.stride_tricks.as_strided(buf[pos:], shape=(n_max, 9), strides=(size, 1))
            same = (heads == heads[0]).all(axis=1)
            k = n_max if same.all() else int(np.argmin(same))
        ops.append(np.full(k, buf[pos], np.uint8))
        bodies.append(pos + 9 + size * np.arange(k, dtype=np.int64))
        lengths.append(np.full(k, length, np.int64))
        pos += size * k
    if not ops:
        return np.zeros(0, np.uint8), np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(ops), np.concatenate(bodies), np.concatenate(lengths)


def read_log(path: str | Path, progress: Callable[[int, int], None] | None = None,
             fields: tuple[str, ...] | None = None) -> LogData:
    """Read a capstan MCAP log.

    :param progress: called as ``progress(bytes_done, bytes_total)`` after each chunk.
    :param fields: cycle fields to read (default all); ``records`` then holds these
        (those the log has) plus the wire fields they are rebuilt from. Reading fewer
        fields is faster (replay needs a third of them).
    :raises DataFormatError: if the file is missing, not MCAP, or not a capstan log
        (no ``/capstan/cycle`` channel with a numpy dtype), or its messages do not match
        their schema.
    """
    p = Path(path)
    try:
        fh = open(p, "rb")
    except OSError as exc:
        raise DataFormatError(f"{p}: cannot open: {exc.strerror or exc}") from exc
    counts, derivations_json = _summary_counts(fh)
    col = _Collector(counts, tuple(fields) if fields is not None else None, derivations_json)
    fh.seek(0)
    truncated = True
    total = p.stat().st_size
    with fh:
        try:
            for rec in _RecordReader(fh, emit_chunks=True, record_size_limit=None).records:
                if isinstance(rec, Chunk):
                    col.walk_chunk(rec)
                    if progress is not None:
                        progress(fh.tell(), total)
                elif isinstance(rec, Metadata):
                    col.metadata[rec.name] = dict(rec.metadata)
                elif isinstance(rec, Schema):
                    col.schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    col.channel(rec)
                elif isinstance(rec, Message):
                    if rec.channel_id in col.payloads:
                        col.add(rec.channel_id, rec.data)
                elif isinstance(rec, Footer):
                    truncated = False
                elif isinstance(rec, DataEnd) and counts:
                    # the summary section was read already (its counts): the rest is
                    # chunk indexes, parsed record by record for nothing
                    truncated = False
                    break
        except DataFormatError as exc:
            raise DataFormatError(f"{p}: {exc}") from exc
        except (McapError, struct.error, zstandard.ZstdError, RuntimeError, ValueError) as exc:
            if not col.channels:
                raise DataFormatError(f"{p}: not a readable MCAP file: {exc}") from exc
            _log.warning("%s: log ends early (%s); reading what is complete", p, exc)
    if truncated:
        _log.warning("%s: no footer (writer was killed?); using complete chunks only", p)
    return _assemble(p, col, truncated)


def _summary_counts(fh: Any) -> tuple[dict[int, int], str | None]:
    """Messages per channel from the file's summary ({} if it has none: cut off), and the
    wire derivations from its metadata index (None if none or no summary)."""
    try:
        reader = SeekingReader(fh)
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            return {}, None
        derivations = None
        if any(ix.name == DERIVATIONS_META for ix in summary.metadata_indexes):
            for meta in reader.iter_metadata():
                if meta.name == DERIVATIONS_META:
                    derivations = meta.metadata.get("derivations")
    except (McapError, struct.error, ValueError, OSError, EOFError):
        return {}, None
    return {int(k): int(v) for k, v in summary.statistics.channel_message_counts.items()}, derivations


def _parse_derivations(derivations_json: str | None) -> list[Derivation]:
    """The logged derivations from the summary ([] if unknown or malformed: the reader
    then decodes every field and reports a malformed entry when rebuilding at the end)."""
    try:
        return [Derivation.from_json(d) for d in json.loads(derivations_json or "[]")]
    except (ValueError, TypeError, DataFormatError):
        return []


def _decode_channel(p: Path, col: _Collector, topic: str) -> np.ndarray | None:
    ch = next((c for c in col.channels.values() if c.topic == topic), None)
    if ch is None:
        return None
    layout = col.layouts.get(ch.id)
    if layout is None:
        raise DataFormatError(f"{p}: channel {topic} is not protobuf with numpy_dtype metadata")
    parts = col.payloads.get(ch.id, [])
    buf = col.buffers.get(ch.id)
    if buf is not None and not parts:
        return buf[0][:buf[1]]
    return np.concatenate(parts) if parts else np.zeros(0, col.full.get(ch.id, layout.dtype))


def _assemble(p: Path, col: _Collector, truncated: bool) -> LogData:
    meta = col.metadata.get("capstan.log", {})
    records = _decode_channel(p, col, CYCLE_TOPIC)
    if records is None:
        raise DataFormatError(f"{p}: no {CYCLE_TOPIC} channel; not a capstan log")
    cyc = next(c for c in col.channels.values() if c.topic == CYCLE_TOPIC)
    if col.derived:                              # rebuilt while decoding; numpy-path rows here
        for a, b in col.slow_rows:
            record_bytes.derive_fields(records[a:b], col.derivations, col.derived)
    elif "record_dtype" in cyc.metadata:
        records = rebuild_derived(records, col.full[cyc.id],
                                  col.metadata.get(DERIVATIONS_META, {}).get("derivations"), p,
                                  stored_fields=col.layouts[cyc.id].dtype.names)
    stats = _decode_channel(p, col, STATS_TOPIC)
    events: list[dict[str, Any]] = []
    ev_ch = next((c for c in col.channels.values() if c.topic == EVENTS_TOPIC), None)
    if ev_ch is not None:
        for raw in col.payloads.get(ev_ch.id, []):
            try:
                events.append(json.loads(bytes(raw)))
            except ValueError as exc:
                raise DataFormatError(f"{p}: unreadable event message: {exc}") from exc
    config_yaml = col.metadata.get("capstan.config", {}).get("yaml", "")
    try:
        # libyaml's safe loader when built in (the pure-Python one takes tens of ms)
        config = yaml.load(config_yaml, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader)) if config_yaml else {}
    except yaml.YAMLError as exc:
        raise DataFormatError(f"{p}: stored config is not valid YAML: {exc}") from exc
    return LogData(p, records, config_yaml, config if isinstance(config, dict) else {}, meta,
                   events, stats, truncated)


def rebuild_derived(stored: np.ndarray, record_dtype: np.dtype, derivations_json: str | None,
                    path: Path | str = "", stored_fields: tuple[str, ...] | None = None) -> np.ndarray:
    """The full cycle records from the stored ones: stored fields copied, every other
    field computed from its wire field with the logged derivation (the drivers' own
    conversion, :mod:`capstan.models.common.wire_units`), bit for bit.

    :raises DataFormatError: if the derivations are missing or malformed, or a field of
        the record is neither stored nor derived.
    """
    have = tuple(stored_fields) if stored_fields is not None else stored.dtype.names
    if stored.dtype == record_dtype:             # decoded straight into the record dtype
        out = stored
    else:
        out = np.zeros(len(stored), record_dtype)
        for name in have:
            if name in record_dtype.names:
                out[name] = stored[name]
    missing = [n for n in record_dtype.names if n not in have]
    if not missing:
        return out
    if not derivations_json:
        raise DataFormatError(f"{path}: the log stores wire values but no '{DERIVATIONS_META}' metadata; "
                              f"cannot rebuild {', '.join(missing)}")
    try:
        items = json.loads(derivations_json)
    except ValueError as exc:
        raise DataFormatError(f"{path}: '{DERIVATIONS_META}' metadata is not JSON: {exc}") from exc
    derivations = {d.field: d for d in (Derivation.from_json(x) for x in items)}
    for name in missing:
        d = derivations.get(name)
        if d is None or d.source not in have:
            raise DataFormatError(f"{path}: field '{name}' is neither stored nor derivable from a stored "
                                  "wire field")
    if wire_decode.supported(record_dtype) and all(record_dtype.fields[n][0] == np.float64 for n in missing):
        try:                                     # compiled, one pass over the records
            record_bytes.derive_fields(out, list(derivations.values()), missing)
        except DataFormatError as exc:
            raise DataFormatError(f"{path}: {exc}") from exc
        return out
    for name in missing:
        d = derivations.get(name)
        if d is None or d.source not in have:
            raise DataFormatError(f"{path}: field '{name}' is neither stored nor derivable from a stored "
                                  "wire field")
        out[name] = apply_ops(stored[d.source].astype(np.float64), d.ops)
    return out


def read_logs(paths: list[str | Path], fields: tuple[str, ...] | None = None) -> LogData:
    """Read a rotated set of files (in the given order) as one log; config and meta
    come from the first file; ``fields`` as :func:`read_log`.

    :raises DataFormatError: as :func:`read_log`, or if the files' dtypes differ.
    """
    parts = [read_log(p, fields=fields) for p in paths]
    if not parts:
        raise DataFormatError("no log files given")
    first = parts[0]
    for part in parts[1:]:
        if part.records.dtype != first.records.dtype:
            raise DataFormatError(f"{part.path}: record dtype differs from {first.path}")
    stats = [x.stats for x in parts if x.stats is not None]
    return LogData(first.path, np.concatenate([x.records for x in parts]), first.config_yaml,
                   first.config, first.meta, [e for x in parts for e in x.events],
                   np.concatenate(stats) if stats else None, any(x.truncated for x in parts))
