"""A small MCAP writer for fixed-size messages in bulk: chunked, zstd at a chosen level,
chunk, message and metadata indexes, a summary that standard readers (and Foxglove) seek with.

Why not ``mcap.writer.Writer``: it compresses chunks at the zstd default level (3) with
no way to choose another and builds Python objects per message (the message, its index
entry). At 1 kHz the log writer spends its time on exactly those, so this module builds
a batch of message records, and their index entries, as numpy arrays and compresses
each chunk at the level it is given. The record layouts come from the MCAP
specification (https://mcap.dev/spec); the other records are serialised by the ``mcap``
package's own record classes.

File layout written::

    magic, Header, Metadata..., Schema..., Channel...,
    (Chunk, MessageIndex per channel in it)..., DataEnd,
    summary: Schema, Channel, Statistics, ChunkIndex, MetadataIndex groups,
    SummaryOffset records, Footer, magic

Message indexes cost 16 uncompressed bytes per message, but Foxglove needs them: its
indexed reader (``@mcap/core`` ``McapIndexedReader``, used for any file with chunk
indexes) refuses a chunk index without message indexes ("Encountered a chunk index
without message indexes and non-zero start and end times", ``ChunkCursor``'s
constructor), and reads only the messages they list (``readMessages`` takes each
message's offset from ``ChunkCursor.loadMessageIndexes``). The Python ``mcap`` reader
would read chunks from chunk indexes alone; Foxglove decides the layout.
``message_index=False`` leaves them out (and then the chunk indexes too, so such readers
fall back to streaming the file) for offline files that only this project reads.

Schemas, channels and metadata are written in the data section before the first chunk
(so a file cut off by a kill is read by streaming) and repeated in the summary.
Message records carry ``sequence`` 0 (the field is optional in MCAP; the cycle number
is in the cycle payload) and ``publish_time`` equal to ``log_time``.
"""

from __future__ import annotations

import struct
import zlib
from collections import defaultdict
from typing import IO

import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (Channel, Chunk, ChunkIndex, DataEnd, Footer, Header, Metadata, MetadataIndex,
                          Schema, Statistics, SummaryOffset)

from capstan.models.common.errors import CapstanError

MAGIC = b"\x89MCAP0\r\n"
#: bytes of a message record before its payload: opcode u8, record length u64,
#: channel id u16, sequence u32, log_time u64, publish_time u64
MESSAGE_HEAD_BYTES = 31
#: zstd level when none is given (zstd's own default: fast, for offline writes); the
#: daemon's writer process uses :data:`capstan.controller.log.writer.LIVE_ZSTD_LEVEL`
DEFAULT_ZSTD_LEVEL = 3


class McapWriteError(CapstanError):
    """The writer was used out of order (after finish, unknown channel) or misconfigured."""


def message_rows(channel_id: int, log_time_ns: np.ndarray, payload: np.ndarray) -> np.ndarray:
    """Message records for fixed-size payloads, one row each.

    :param log_time_ns: int64 log times [ns], also used as publish times.
    :param payload: ``(n, size)`` uint8 rows, one message payload each.
    :returns: ``(n, MESSAGE_HEAD_BYTES + size)`` uint8; ``rows.tobytes()`` is the records.
    """
    n, size = payload.shape
    rows = np.empty((n, MESSAGE_HEAD_BYTES + size), np.uint8)
    head = struct.pack("<BQHI", Opcode.MESSAGE, 2 + 4 + 8 + 8 + size, channel_id, 0)
    rows[:, :15] = np.frombuffer(head, np.uint8)
    t = np.ascontiguousarray(log_time_ns, dtype="<u8").view(np.uint8).reshape(n, 8)
    rows[:, 15:23] = t
    rows[:, 23:31] = t
    rows[:, 31:] = payload
    return rows


class McapChunkWriter:
    """Writes one MCAP file to an open binary stream.

    :param stream: writable binary file object (``tell()`` must work).
    :param compression: ``"zstd"``, ``"lz4"`` or ``""`` (none).
    :param zstd_level: zstd level for ``"zstd"`` chunks (1..22).
    :param chunk_size_bytes: close a chunk once its uncompressed size passes this.
    :param message_index: write a MessageIndex record per channel after each chunk and
        chunk indexes in the summary (what Foxglove needs to open the file indexed).
    :raises McapWriteError: on an unknown compression or a zstd level out of range.
    """

    def __init__(self, stream: IO[bytes], compression: str = "zstd", zstd_level: int = DEFAULT_ZSTD_LEVEL,
                 chunk_size_bytes: int = 1 << 20, message_index: bool = True) -> None:
        if compression not in ("zstd", "lz4", ""):
            raise McapWriteError(f"compression must be zstd, lz4 or '' (none), got {compression!r}")
        if compression == "zstd" and not 1 <= int(zstd_level) <= 22:
            raise McapWriteError(f"zstd level must be 1..22, got {zstd_level}")
        self._fh = stream
        self.compression = compression
        self.zstd_level = int(zstd_level)
        self._zstd = zstandard.ZstdCompressor(level=self.zstd_level) if compression == "zstd" else None
        self.chunk_size_bytes = int(chunk_size_bytes)
        self.message_index = bool(message_index)
        self._schemas: list[Schema] = []
        self._channels: dict[int, Channel] = {}
        self._meta_index: list[MetadataIndex] = []
        self._chunk_index: list[ChunkIndex] = []
        self._chunks = 0
        self._counts: defaultdict[int, int] = defaultdict(int)
        self._t_first: int | None = None
        self._t_last = 0
        self._parts: list[bytes] = []
        self._index: defaultdict[int, list[np.ndarray]] = defaultdict(list)   # channel -> (time, offset) rows
        self._part_bytes = 0
        self._part_t = (0, 0)
        self._part_n = 0
        self._finished = False

    # ------------------------------------------------------------------ records
    def _record(self, record: object) -> None:
        b = RecordBuilder()
        record.write(b)                              # type: ignore[attr-defined]
        self._fh.write(b.end())

    def start(self, library: str = "capstan", profile: str = "") -> None:
        """Magic and Header record."""
        self._fh.write(MAGIC)
        self._record(Header(profile=profile, library=library))

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A Metadata record (indexed in the summary); closes the open chunk first."""
        self._check_open()
        self._finish_chunk()
        offset = self._fh.tell()
        self._record(Metadata(name=name, metadata=dict(data)))
        self._meta_index.append(MetadataIndex(offset=offset, length=self._fh.tell() - offset, name=name))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Write a Schema record; returns its id (1, 2, ...)."""
        self._check_open()
        self._finish_chunk()
        schema = Schema(id=len(self._schemas) + 1, name=name, encoding=encoding, data=bytes(data))
        self._schemas.append(schema)
        self._record(schema)
        return schema.id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int,
                         metadata: dict[str, str] | None = None) -> int:
        """Write a Channel record; returns its id (1, 2, ...)."""
        self._check_open()
        self._finish_chunk()
        ch = Channel(id=len(self._channels) + 1, topic=topic, message_encoding=message_encoding,
                     schema_id=schema_id, metadata=dict(metadata or {}))
        self._channels[ch.id] = ch
        self._record(ch)
        return ch.id

    def copy_schema(self, schema: Schema) -> None:
        """Write a Schema record of another file with its own id (recovery)."""
        self._check_open()
        self._finish_chunk()
        if all(x.id != schema.id for x in self._schemas):
            self._schemas.append(schema)
        self._record(schema)

    def copy_channel(self, channel: Channel) -> None:
        """Write a Channel record of another file with its own id (recovery)."""
        self._check_open()
        self._finish_chunk()
        self._channels[channel.id] = channel
        self._record(channel)

    # ------------------------------------------------------------------ messages
    def add_messages(self, channel_id: int, log_time_ns: np.ndarray, payload: np.ndarray) -> None:
        """Append fixed-size messages (rows of ``payload``) with their log times [ns].

        :raises McapWriteError: for an unregistered channel or after :meth:`finish`.
        """
        self._check_open()
        if channel_id not in self._channels:
            raise McapWriteError(f"channel {channel_id} is not registered")
        n = len(payload)
        if not n:
            return
        t = np.asarray(log_time_ns, dtype=np.int64)
        rows = message_rows(channel_id, t, payload)
        row_bytes = rows.shape[1]
        i = 0
        while i < n:
            room = max(1, -(-(self.chunk_size_bytes - self._part_bytes) // row_bytes))
            j = min(n, i + room)
            entries = np.empty((j - i, 2), "<u8")
            entries[:, 0] = t[i:j]
            entries[:, 1] = self._part_bytes + row_bytes * np.arange(j - i, dtype=np.uint64)
            self._index[channel_id].append(entries)
            self._append(rows[i:j].tobytes(), int(t[i:j].min()), int(t[i:j].max()), j - i)
            if self._part_bytes >= self.chunk_size_bytes:
                self._finish_chunk()
            i = j
        self._counts[channel_id] += n

    def add_message(self, channel_id: int, log_time_ns: int, data: bytes) -> None:
        """Append one message of any size.

        :raises McapWriteError: for an unregistered channel or after :meth:`finish`.
        """
        self._check_open()
        if channel_id not in self._channels:
            raise McapWriteError(f"channel {channel_id} is not registered")
        t = int(log_time_ns)
        head = struct.pack("<BQHIQQ", Opcode.MESSAGE, 22 + len(data), channel_id, 0, t, t)
        self._index[channel_id].append(np.array([[t, self._part_bytes]], "<u8"))
        self._append(head + bytes(data), t, t, 1)
        self._counts[channel_id] += 1
        if self._part_bytes >= self.chunk_size_bytes:
            self._finish_chunk()

    def _append(self, blob: bytes, t_min: int, t_max: int, n: int) -> None:
        if self._part_n == 0:
            self._part_t = (t_min, t_max)
        else:
            self._part_t = (min(self._part_t[0], t_min), max(self._part_t[1], t_max))
        self._parts.append(blob)
        self._part_bytes += len(blob)
        self._part_n += n
        self._t_first = t_min if self._t_first is None else min(self._t_first, t_min)
        self._t_last = max(self._t_last, t_max)

    def _finish_chunk(self) -> None:
        if not self._part_n:
            return
        data = b"".join(self._parts)
        if self.compression == "zstd":
            assert self._zstd is not None
            packed = self._zstd.compress(data)
        elif self.compression == "lz4":
            import lz4.frame
            packed = lz4.frame.compress(data)
        else:
            packed = data
        start = self._fh.tell()
        self._record(Chunk(compression=self.compression, data=packed, message_start_time=self._part_t[0],
                           message_end_time=self._part_t[1], uncompressed_crc=zlib.crc32(data),
                           uncompressed_size=len(data)))
        chunk_length = self._fh.tell() - start
        self._chunks += 1
        index_offsets: dict[int, int] = {}
        if self.message_index:
            for ch in sorted(self._index):
                entries = np.concatenate(self._index[ch])
                entries = entries[np.argsort(entries[:, 0], kind="stable")]
                index_offsets[ch] = self._fh.tell()
                body = entries.tobytes()
                self._fh.write(struct.pack("<BQHI", Opcode.MESSAGE_INDEX, 2 + 4 + len(body), ch, len(body)))
                self._fh.write(body)
            self._chunk_index.append(ChunkIndex(
                message_start_time=self._part_t[0], message_end_time=self._part_t[1], chunk_start_offset=start,
                chunk_length=chunk_length, message_index_offsets=index_offsets,
                message_index_length=self._fh.tell() - start - chunk_length, compression=self.compression,
                compressed_size=len(packed), uncompressed_size=len(data)))
        self._parts, self._part_bytes, self._part_n = [], 0, 0
        self._index.clear()

    def copy_chunk(self, chunk: Chunk, index: dict[int, np.ndarray]) -> None:
        """Append a complete Chunk record of another file as it is (no recompression),
        with message indexes built from ``index`` (channel -> ``(n, 2)`` uint64 rows of
        log time [ns] and offset in the uncompressed chunk). For :mod:`capstan.controller.log.recover`.

        :raises McapWriteError: after :meth:`finish` or for an unregistered channel.
        """
        self._check_open()
        self._finish_chunk()
        for ch in index:
            if ch not in self._channels:
                raise McapWriteError(f"chunk holds messages of unregistered channel {ch}")
        start = self._fh.tell()
        self._record(chunk)
        chunk_length = self._fh.tell() - start
        self._chunks += 1
        offsets: dict[int, int] = {}
        for ch in sorted(index):
            entries = np.ascontiguousarray(index[ch], "<u8")
            entries = entries[np.argsort(entries[:, 0], kind="stable")]
            offsets[ch] = self._fh.tell()
            body = entries.tobytes()
            self._fh.write(struct.pack("<BQHI", Opcode.MESSAGE_INDEX, 2 + 4 + len(body), ch, len(body)))
            self._fh.write(body)
            self._counts[ch] += len(entries)
        self._chunk_index.append(ChunkIndex(
            message_start_time=chunk.message_start_time, message_end_time=chunk.message_end_time,
            chunk_start_offset=start, chunk_length=chunk_length, message_index_offsets=offsets,
            message_index_length=self._fh.tell() - start - chunk_length, compression=chunk.compression,
            compressed_size=len(chunk.data), uncompressed_size=chunk.uncompressed_size))
        if index:
            t0, t1 = chunk.message_start_time, chunk.message_end_time
            self._t_first = t0 if self._t_first is None else min(self._t_first, t0)
            self._t_last = max(self._t_last, t1)

    # ------------------------------------------------------------------ policy
    @property
    def pending_bytes(self) -> int:
        """Uncompressed bytes in the open chunk."""
        return self._part_bytes

    def tell(self) -> int:
        """Bytes written to the stream so far (the open chunk not included)."""
        return int(self._fh.tell())

    def flush(self) -> None:
        """Close the open chunk (if it holds messages) and flush the stream to the OS."""
        if not self._finished:
            self._finish_chunk()
        self._fh.flush()

    def _check_open(self) -> None:
        if self._finished:
            raise McapWriteError("the MCAP file is already finished")

    def finish(self) -> None:
        """Close the open chunk, write DataEnd, the summary and the footer. Idempotent;
        does not close the stream."""
        if self._finished:
            return
        self._finish_chunk()
        self._record(DataEnd(data_section_crc=0))
        summary_start = self._fh.tell()
        b = RecordBuilder()
        offsets: list[SummaryOffset] = []

        def group(opcode: int, records: list) -> None:
            if not records:
                return
            start = b.count
            for r in records:
                r.write(b)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + start,
                                         group_length=b.count - start))

        group(Opcode.SCHEMA, self._schemas)
        group(Opcode.CHANNEL, list(self._channels.values()))
        group(Opcode.STATISTICS, [Statistics(
            message_count=sum(self._counts.values()), schema_count=len(self._schemas),
            channel_count=len(self._channels), attachment_count=0, metadata_count=len(self._meta_index),
            chunk_count=self._chunks, message_start_time=self._t_first or 0,
            message_end_time=self._t_last, channel_message_counts=dict(self._counts))])
        group(Opcode.CHUNK_INDEX, self._chunk_index)
        group(Opcode.METADATA_INDEX, self._meta_index)
        summary_offset_start = summary_start + b.count
        for off in offsets:
            off.write(b)
        summary = b.end()
        crc = zlib.crc32(summary)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start, summary_offset_start), crc)
        self._fh.write(summary)
        self._record(Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
                            summary_crc=crc))
        self._fh.write(MAGIC)
        self._fh.flush()
        self._finished = True
