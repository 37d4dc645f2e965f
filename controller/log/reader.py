"""Read a capstan MCAP log back: cycle records as a structured array, the stored config,
the log metadata, events and stats.

Reads by streaming (no summary needed), so a file whose writer was killed is read up
to its last complete chunk and flagged ``truncated``. Each chunk is decompressed and
walked by :class:`capstan.controller.log.chunk_walk.Collector`; the cycle messages are
decoded by the compiled path of :mod:`capstan.controller.log.wire_decode`.
"""

from __future__ import annotations

import json
import logging
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import yaml
import zstandard
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, Footer, Message, McapRecord, Metadata, Schema
from mcap.reader import SeekingReader
from mcap.stream_reader import StreamReader

from capstan.controller.log.mcap_log import CYCLE_TOPIC, DERIVATIONS_META, EVENTS_TOPIC, STATS_TOPIC
from capstan.controller.log import record_bytes, wire_decode
from capstan.controller.log.chunk_walk import Collector
from capstan.models.common.errors import DataFormatError
from capstan.models.common.wire_units import Derivation, apply_ops

_log = logging.getLogger(__name__)



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
    col = Collector(counts, tuple(fields) if fields is not None else None, derivations_json)
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
    if progress is not None:
        progress(total, total)                   # the summary section is not walked
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


def _decode_channel(p: Path, col: Collector, topic: str) -> np.ndarray | None:
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


def _assemble(p: Path, col: Collector, truncated: bool) -> LogData:
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
