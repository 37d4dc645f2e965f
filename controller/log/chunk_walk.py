"""Collecting a capstan log's records while it is streamed: each chunk decompressed and
walked, the cycle messages decoded by the compiled path
(:mod:`capstan.controller.log.wire_decode`) or, for other fixed-size protobuf
channels, as strided numpy views in place; schemas, channels, metadata and other
messages kept for :mod:`capstan.controller.log.reader`.
"""

from __future__ import annotations

import io
import json
from typing import Any

import lz4.frame
import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.records import Channel, Chunk, Schema

from capstan.controller.log import record_bytes, wire_decode
from capstan.controller.log.mcap_log import CYCLE_TOPIC
from capstan.controller.log.ring import dtype_from_json
from capstan.controller.log.schema import ProtoLayout, build_layout
from capstan.models.common.errors import DataFormatError
from capstan.models.common.wire_units import Derivation

_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE = 0x03, 0x04, 0x05
_MSG_HEAD = 22  # channel u16, sequence u32, log_time u64, publish_time u64


class Collector:
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


def _parse_derivations(derivations_json: str | None) -> list[Derivation]:
    """The logged derivations from the summary ([] if unknown or malformed: the reader
    then decodes every field and reports a malformed entry when rebuilding at the end)."""
    try:
        return [Derivation.from_json(d) for d in json.loads(derivations_json or "[]")]
    except (ValueError, TypeError, DataFormatError):
        return []
