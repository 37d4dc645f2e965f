"""Rewrite an MCAP log cut off by a crash into a valid, indexed file.

A writer killed mid-file leaves chunks and records but no summary or footer; readers
that seek (``mcap``'s ``make_reader``, Foxglove) refuse it, and the last record may be
cut in the middle. :func:`recover_log` streams the file and keeps everything that is
complete: the header, schemas, channels and metadata, and every complete chunk, copied
byte for byte (no recompression). Message indexes are rebuilt from each chunk's own
content (decompressed and scanned), so a chunk whose index records were cut is kept
too. Then the summary (schemas, channels, statistics, chunk and metadata indexes) and
the footer are written. A file that already ends with a footer is left alone.

The output is written next to the target and renamed over it only when complete, so a
crash during recovery never loses the original.
"""

from __future__ import annotations

import logging
import os
import struct
from dataclasses import dataclass
from pathlib import Path

import lz4.frame
import numpy as np
import zstandard
from mcap.exceptions import McapError
from mcap.records import Channel, Chunk, DataEnd, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from capstan.controller.log.mcap_writer import McapChunkWriter
from capstan.models.common.errors import DataFormatError

_log = logging.getLogger(__name__)

_OP_MESSAGE = 0x05


@dataclass
class RecoverResult:
    """What :func:`recover_log` did.

    :ivar path: the recovered file.
    :ivar was_complete: the file had a footer; nothing was rewritten.
    :ivar chunks: complete chunks kept.
    :ivar messages: messages kept (all channels).
    :ivar bytes_dropped: bytes after the last complete record (the cut-off tail).
    :ivar stop_reason: why reading stopped (end of file, or the error at the cut).
    """

    path: Path
    was_complete: bool
    chunks: int = 0
    messages: int = 0
    bytes_dropped: int = 0
    stop_reason: str = ""


def _decompress(chunk: Chunk) -> bytes:
    if chunk.compression == "zstd":
        return zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=chunk.uncompressed_size)
    if chunk.compression == "lz4":
        return lz4.frame.decompress(chunk.data)
    if chunk.compression == "":
        return chunk.data
    raise DataFormatError(f"unsupported chunk compression {chunk.compression!r}")


def chunk_message_index(chunk: Chunk) -> dict[int, np.ndarray]:
    """channel -> ``(n, 2)`` rows (log time [ns], offset in the uncompressed chunk) of the
    messages in ``chunk``.

    :raises DataFormatError: if the chunk does not decompress to whole records.
    """
    data = _decompress(chunk)
    out: dict[int, list[tuple[int, int]]] = {}
    pos, end = 0, len(data)
    while pos < end:
        if pos + 9 > end:
            raise DataFormatError(f"chunk at time {chunk.message_start_time}: record header cut at byte {pos}")
        op = data[pos]
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        if pos + 9 + length > end:
            raise DataFormatError(f"chunk at time {chunk.message_start_time}: record cut at byte {pos}")
        if op == _OP_MESSAGE:
            ch, _seq, log_time = struct.unpack_from("<HIQ", data, pos + 9)
            out.setdefault(ch, []).append((log_time, pos))
        pos += 9 + length
    return {ch: np.array(rows, dtype="<u8").reshape(-1, 2) for ch, rows in out.items()}


def recover_log(path: str | Path, out: str | Path | None = None) -> RecoverResult:
    """Rewrite ``path`` (cut off by a crash) into a valid indexed MCAP file.

    :param out: where to write (default: replace ``path`` once the rewrite is complete).
    :raises DataFormatError: if the file is missing or not MCAP at all (no header).
    """
    src = Path(path)
    dst = Path(out) if out is not None else src
    tmp = dst.with_name(dst.name + ".recovering")
    try:
        fh = open(src, "rb")
    except OSError as exc:
        raise DataFormatError(f"{src}: cannot open: {exc.strerror or exc}") from exc
    res = RecoverResult(dst, was_complete=False)
    size = os.fstat(fh.fileno()).st_size
    kept_end = 0
    with fh, open(tmp, "wb") as oh:
        w = McapChunkWriter(oh, "")
        started = False
        try:
            for rec in StreamReader(fh, emit_chunks=True, record_size_limit=None, validate_crcs=False).records:
                if not started:
                    w.start(library="capstan (recovered)")
                    started = True
                if isinstance(rec, Footer):
                    res.was_complete = True
                    break
                if isinstance(rec, Chunk):
                    index = chunk_message_index(rec)
                    w.copy_chunk(rec, index)
                    res.chunks += 1
                    res.messages += sum(len(v) for v in index.values())
                elif isinstance(rec, Schema):
                    w.copy_schema(rec)
                elif isinstance(rec, Channel):
                    w.copy_channel(rec)
                elif isinstance(rec, Metadata):
                    w.add_metadata(rec.name, dict(rec.metadata))
                elif isinstance(rec, Message):
                    w.add_message(rec.channel_id, rec.log_time, rec.data)
                    res.messages += 1
                elif isinstance(rec, DataEnd):
                    continue
                kept_end = fh.tell()
            res.stop_reason = "footer" if res.was_complete else "end of file"
        except (McapError, struct.error, EOFError, ValueError, zstandard.ZstdError, RuntimeError,
                DataFormatError) as exc:
            res.stop_reason = f"{type(exc).__name__}: {exc}"
        if not started:
            oh.close()
            tmp.unlink(missing_ok=True)
            raise DataFormatError(f"{src}: not an MCAP file ({res.stop_reason or 'empty'})")
        if res.was_complete:
            oh.close()
            tmp.unlink(missing_ok=True)
            if dst != src:
                dst.write_bytes(src.read_bytes())
            return res
        w.finish()
        oh.flush()
        os.fsync(oh.fileno())
    res.bytes_dropped = max(0, size - kept_end)
    os.replace(tmp, dst)
    _log.info("%s: recovered %d chunks, %d messages; %d bytes cut off (%s)", dst, res.chunks,
              res.messages, res.bytes_dropped, res.stop_reason)
    return res


_MAGIC = b"\x89MCAP0\r\n"


def _open_by_any_process(path: Path) -> bool:
    """True if some process has ``path`` open (scans /proc/*/fd; False where unreadable)."""
    target = os.path.realpath(path)
    proc = Path("/proc")
    for d in proc.iterdir() if proc.is_dir() else ():
        if not d.name.isdigit():
            continue
        try:
            for fd in (d / "fd").iterdir():
                try:
                    if os.readlink(fd) == target:
                        return True
                except OSError:
                    continue
        except OSError:
            continue
    return False


def recover_cut_logs(directory: str | Path, prefix: str = "capstan") -> list[RecoverResult]:
    """Recover every ``{prefix}_*.mcap`` in ``directory`` that ends without the MCAP magic
    (cut off by a crash of daemon and writer together) and that no process has open.
    Called at start-up, so the logs of a previous crash open everywhere.

    :returns: what was recovered (files that could not be are logged and skipped).
    """
    done: list[RecoverResult] = []
    for f in sorted(Path(directory).glob(f"{prefix}_*.mcap")):
        try:
            size = f.stat().st_size
            with open(f, "rb") as fh:
                fh.seek(max(0, size - len(_MAGIC)))
                if fh.read() == _MAGIC:
                    continue
        except OSError:
            continue
        if _open_by_any_process(f):
            continue
        try:
            done.append(recover_log(f))
        except (DataFormatError, OSError) as exc:
            _log.error("%s: cut off and not recoverable: %s", f, exc)
    return done

