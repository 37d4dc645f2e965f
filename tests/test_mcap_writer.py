"""The bulk MCAP writer: files that the ``mcap`` package's own readers (seeking, with the
summary, and streaming, with CRCs) read back message for message; chunking, zstd level,
record fields; misuse refused."""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np
import pytest
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.reader import NonSeekingReader, SeekingReader
from mcap.records import Chunk, Footer, Message
from mcap.stream_reader import StreamReader

from capstan.controller.log.mcap_writer import MESSAGE_HEAD_BYTES, McapChunkWriter, McapWriteError, message_rows


def _payloads(n: int, size: int, seed: int = 0) -> np.ndarray:
    """Rows of half-noisy, half-constant bytes (compressible, not trivially)."""
    rng = np.random.default_rng(seed)
    rows = np.zeros((n, size), np.uint8)
    rows[:, : size // 2] = rng.integers(0, 256, (n, size // 2))
    rows[:, size // 2:] = np.arange(size - size // 2) % 7
    return rows


def _write(compression: str = "zstd", level: int = 15, chunk: int = 1 << 20, n: int = 3000,
           size: int = 40) -> tuple[bytes, np.ndarray, np.ndarray]:
    buf = io.BytesIO()
    w = McapChunkWriter(buf, compression, level, chunk)
    w.start()
    w.add_metadata("capstan.config", {"yaml": "a: 1\n"})
    sid = w.register_schema("capstan.Cycle", "protobuf", b"\x0a\x00")
    ch = w.register_channel("/capstan/cycle", "protobuf", sid, {"numpy_dtype": "x"})
    eid = w.register_schema("capstan.Event", "jsonschema", b"{}")
    ev = w.register_channel("/capstan/events", "json", eid)
    rows = _payloads(n, size)
    t = 5_000_000_000 + np.arange(n, dtype=np.int64) * 1_000_000 + (np.arange(n) % 3) * 7
    w.add_messages(ch, t[:1000], rows[:1000])
    w.add_message(ev, int(t[999]), b'{"kind": 3}')
    w.add_messages(ch, t[1000:], rows[1000:])
    w.finish()
    w.finish()                                            # idempotent
    return buf.getvalue(), rows, t


def test_seeking_reader_uses_summary_and_gets_every_message_back() -> None:
    data, rows, t = _write()
    reader = SeekingReader(io.BytesIO(data), validate_crcs=True)
    summ = reader.get_summary()
    assert summ is not None
    st = summ.statistics
    assert st.message_count == len(rows) + 1 and st.channel_count == 2 and st.schema_count == 2
    assert st.channel_message_counts == {1: len(rows), 2: 1} and st.metadata_count == 1
    assert st.message_start_time == t[0] and st.message_end_time == t[-1]
    assert st.chunk_count == len(summ.chunk_indexes) >= 1
    assert summ.channels[1].metadata == {"numpy_dtype": "x"} and summ.schemas[2].encoding == "jsonschema"
    got = [(ch.topic, m) for _, ch, m in reader.iter_messages(log_time_order=False)]
    cyc = [m for topic, m in got if topic == "/capstan/cycle"]
    assert len(cyc) == len(rows)
    assert all(m.data == rows[i].tobytes() and m.log_time == t[i] == m.publish_time and m.sequence == 0
               for i, m in enumerate(cyc))
    assert [m.data for topic, m in got if topic == "/capstan/events"] == [b'{"kind": 3}']
    assert [m.name for m in reader.iter_metadata()] == ["capstan.config"]


def test_streaming_reader_validates_crcs_and_footer_crc_is_right() -> None:
    data, rows, _ = _write()
    n = sum(1 for _ in NonSeekingReader(io.BytesIO(data), validate_crcs=True).iter_messages())
    assert n == len(rows) + 1
    footer = [r for r in StreamReader(io.BytesIO(data)).records if isinstance(r, Footer)][0]
    summary = data[footer.summary_start:len(data) - 8 - (1 + 8 + 20)]
    crc = zlib.crc32(struct.pack("<BQQQ", 0x02, 20, footer.summary_start, footer.summary_offset_start),
                     zlib.crc32(summary))
    assert footer.summary_crc == crc


def _indexed_read(data: bytes) -> list[tuple[int, int, bytes]]:
    """(channel, log_time, payload) of every message, found the way Foxglove's indexed
    reader finds them: chunk indexes from the summary, then each chunk's MessageIndex
    records at the offsets the chunk index gives, then the message at each listed offset
    of the decompressed chunk. Raises like that reader on a chunk index with messages
    but no message indexes."""
    summ = SeekingReader(io.BytesIO(data)).get_summary()
    assert summ is not None
    out = []
    for ci in summ.chunk_indexes:
        if ci.message_index_length == 0 and (ci.message_start_time or ci.message_end_time):
            raise AssertionError("chunk index without message indexes and non-zero times")
        chunk = next(r for r in StreamReader(io.BytesIO(data[ci.chunk_start_offset:]), skip_magic=True,
                                             emit_chunks=True).records)
        assert isinstance(chunk, Chunk)
        raw = zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=chunk.uncompressed_size) \
            if chunk.compression == "zstd" else chunk.data
        for ch, off in ci.message_index_offsets.items():
            op, length, ch_id, nbytes = struct.unpack_from("<BQHI", data, off)
            assert (op, ch_id, length) == (0x07, ch, 6 + nbytes)
            entries = np.frombuffer(data, "<u8", nbytes // 8, off + 15).reshape(-1, 2)
            assert np.all(np.diff(entries[:, 0].astype(np.int64)) >= 0)         # sorted by log time
            for t, pos in entries.tolist():
                assert raw[pos] == 0x05
                m = Message.read(ReadDataStream(io.BytesIO(raw[pos + 9:])),
                                 int.from_bytes(raw[pos + 1:pos + 9], "little"))
                assert m.channel_id == ch and m.log_time == t
                assert ci.message_start_time <= t <= ci.message_end_time
                out.append((ch, t, m.data))
    return out


def test_message_indexes_list_every_message_as_foxglove_reads_them() -> None:
    data, rows, t = _write(chunk=16 << 10)
    got = _indexed_read(data)
    cyc = sorted((tt, d) for ch, tt, d in got if ch == 1)
    assert [tt for tt, _ in cyc] == t.tolist() and [d for _, d in cyc] == [r.tobytes() for r in rows]
    assert [d for ch, _, d in got if ch == 2] == [b'{"kind": 3}']


def test_without_message_indexes_no_chunk_index_claims_messages() -> None:
    buf = io.BytesIO()
    w = McapChunkWriter(buf, message_index=False)
    w.start()
    ch = w.register_channel("/x", "json", 0)
    w.add_messages(ch, np.arange(10, dtype=np.int64) + 1, np.ones((10, 3), np.uint8))
    w.finish()
    summ = SeekingReader(io.BytesIO(buf.getvalue())).get_summary()
    assert summ is not None and summ.chunk_indexes == [] and summ.statistics.chunk_count == 1
    assert sum(1 for _ in NonSeekingReader(io.BytesIO(buf.getvalue())).iter_messages()) == 10


def test_chunks_close_at_the_size_limit_and_cover_their_times() -> None:
    data, rows, t = _write(chunk=16 << 10)
    summ = SeekingReader(io.BytesIO(data)).get_summary()
    assert summ is not None
    row_bytes = MESSAGE_HEAD_BYTES + rows.shape[1]
    idx = summ.chunk_indexes
    assert len(idx) >= len(rows) * row_bytes // (16 << 10)
    assert all(ci.uncompressed_size < (16 << 10) + 1000 * row_bytes for ci in idx)
    assert all(ci.compression == "zstd" and ci.compressed_size < ci.uncompressed_size for ci in idx)
    starts = [ci.message_start_time for ci in idx]
    assert starts == sorted(starts) and starts[0] == t[0] and idx[-1].message_end_time == t[-1]


def test_zstd_level_is_applied() -> None:
    small, _, _ = _write(level=19, size=120)
    fast, _, _ = _write(level=1, size=120)
    assert len(small) < len(fast)


@pytest.mark.parametrize("compression", ["lz4", ""])
def test_other_compressions_are_readable(compression: str) -> None:
    data, rows, _ = _write(compression=compression)
    chunks = [r for r in StreamReader(io.BytesIO(data), emit_chunks=True).records if isinstance(r, Chunk)]
    assert chunks and all(c.compression == compression for c in chunks)
    n = sum(1 for _ in SeekingReader(io.BytesIO(data), validate_crcs=True).iter_messages())
    assert n == len(rows) + 1


def test_message_rows_follow_the_record_layout() -> None:
    rows = message_rows(3, np.array([7, 2**40 + 5]), np.full((2, 4), 0xAB, np.uint8))
    rec = Message.read(ReadDataStream(io.BytesIO(rows[1, 9:].tobytes())), len(rows[1]) - 9)
    assert rows[1, 0] == 0x05 and int.from_bytes(rows[1, 1:9].tobytes(), "little") == 22 + 4
    assert (rec.channel_id, rec.sequence, rec.log_time, rec.publish_time) == (3, 0, 2**40 + 5, 2**40 + 5)
    assert rec.data == b"\xab" * 4


def test_misuse_is_refused() -> None:
    with pytest.raises(McapWriteError, match="compression"):
        McapChunkWriter(io.BytesIO(), "gzip")
    with pytest.raises(McapWriteError, match="level"):
        McapChunkWriter(io.BytesIO(), "zstd", 23)
    w = McapChunkWriter(io.BytesIO())
    w.start()
    with pytest.raises(McapWriteError, match="not registered"):
        w.add_messages(1, np.zeros(1, np.int64), np.zeros((1, 4), np.uint8))
    with pytest.raises(McapWriteError, match="not registered"):
        w.add_message(1, 0, b"x")
    w.finish()
    with pytest.raises(McapWriteError, match="finished"):
        w.register_schema("s", "protobuf", b"")
