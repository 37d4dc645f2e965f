"""Binary frame of the 4-channel load-cell amplifier: build, parse, stream parser.

Pure functions on bytes, no I/O. The amplifier (modelled on common 4-channel
strain-gauge amplifiers with a binary output mode) streams one frame per sample at
1 kHz, 19 bytes::

    offset  size  content
    0       1     start byte 0xAA
    1       16    four IEEE-754 float32, big-endian, bridge signal in mV/V, channel order
                  0 upper input-side, 1 upper output-side, 2 lower output-side,
                  3 lower input-side (the :class:`capstan.drivers.interfaces.LoadCellSample` order)
    17      1     checksum: sum of bytes 1..16 modulo 256
    18      1     end byte 0x55

At 1 kHz the stream needs 19 kB/s, i.e. at least 230400 Bd with 8N1 framing.

Conversion to tension (driver side, per channel): ``T_N = scale_N_per_mV_V * raw_mV_V +
offset_N - tare_N``.

Accounting of :class:`LoadCellParser`: while in sync, the bytes where the next frame
must begin either form a valid frame (good) or are counted as one bad frame, after
which the parser loses sync (one resync) and hunts for a start byte whose end byte
and checksum match. While hunting, a candidate with matching start and end bytes but
a wrong checksum or non-finite values counts as a bad frame too; other bytes are
skipped silently. The stream starts out hunting, so a partial first frame is not
counted. ``bytes_skipped`` counts every byte that belongs to no returned frame.

Bound: the frame has a fixed length and no length field, so no byte sequence can make
the parser wait for more than one frame (19 bytes): a candidate is judged as soon as
its 19 bytes are in, and the hunt resumes one byte after a rejected start byte.
"""

from __future__ import annotations

import math
import struct

from capstan.drivers.interfaces import LinkStats

START_BYTE = 0xAA
END_BYTE = 0x55
FRAME_LEN = 19
N_CHANNELS = 4
_VALUES = struct.Struct(">4f")


def frame_checksum(values_bytes: bytes | bytearray | memoryview) -> int:
    """Checksum over the 16 value bytes: their sum modulo 256."""
    return sum(values_bytes) & 0xFF


def build_frame(raw_mV_V: tuple[float, float, float, float] | list[float]) -> bytes:
    """One 19-byte frame carrying four bridge signals [mV/V] (rounded to float32)."""
    body = _VALUES.pack(*raw_mV_V)
    return bytes((START_BYTE,)) + body + bytes((frame_checksum(body), END_BYTE))


def parse_frame(frame: bytes | bytearray | memoryview) -> tuple[float, float, float, float] | None:
    """Values [mV/V] of one frame, or None if it is not exactly one valid frame."""
    if len(frame) != FRAME_LEN or frame[0] != START_BYTE or frame[18] != END_BYTE:
        return None
    if frame_checksum(frame[1:17]) != frame[17]:
        return None
    vals = _VALUES.unpack_from(frame, 1)
    if not all(math.isfinite(v) for v in vals):
        return None
    return vals  # type: ignore[return-value]


class LoadCellParser:
    """Incremental parser of the amplifier byte stream (see the module docstring).

    ``feed(data)`` returns the decoded frames as 4-tuples [mV/V] in arrival order and
    counts good frames, bad frames and resyncs in ``stats``. Never raises on malformed
    input; at most one partial frame is kept between calls.
    """

    def __init__(self, stats: LinkStats | None = None) -> None:
        self.stats = stats if stats is not None else LinkStats()
        self._buf = bytearray()
        self._in_sync = False
        self._bytes_in = 0
        self._frames = 0
        self._skipped_reported = 0

    def reset(self) -> None:
        """Drop buffered bytes (they count as skipped) and hunt for the next frame."""
        self._buf.clear()
        self._in_sync = False
        self._report_skipped()

    def _report_skipped(self) -> None:
        skipped = self._bytes_in - FRAME_LEN * self._frames - len(self._buf)
        self.stats.bytes_skipped += skipped - self._skipped_reported
        self._skipped_reported = skipped

    @property
    def buffered(self) -> int:
        """Bytes waiting for the rest of a frame."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[tuple[float, float, float, float]]:
        """Add bytes, return all complete valid frames (values in mV/V)."""
        buf = self._buf
        buf += data
        self._bytes_in += len(data)
        n = len(buf)
        out: list[tuple[float, float, float, float]] = []
        stats = self.stats
        unpack = _VALUES.unpack_from
        i = 0
        while n - i >= FRAME_LEN:
            if self._in_sync:
                vals = parse_frame(buf[i:i + FRAME_LEN])
                if vals is not None:
                    out.append(vals)
                    stats.good_frames += 1
                    i += FRAME_LEN
                    continue
                stats.bad_frames += 1
                stats.resyncs += 1
                self._in_sync = False
                i += 1
            j = buf.find(START_BYTE, i, n - FRAME_LEN + 1)
            if j < 0:
                i = n - FRAME_LEN + 1
                break
            i = j
            if buf[j + 18] != END_BYTE:
                i = j + 1
                continue
            body = buf[j + 1:j + 17]
            if frame_checksum(body) != buf[j + 17]:
                stats.bad_frames += 1
                i = j + 1
                continue
            vals = unpack(buf, j + 1)
            if not all(math.isfinite(v) for v in vals):
                stats.bad_frames += 1
                i = j + 1
                continue
            out.append(vals)
            stats.good_frames += 1
            self._in_sync = True
            i = j + FRAME_LEN
        if i:
            del buf[:i]
        self._frames += len(out)
        self._report_skipped()
        return out
