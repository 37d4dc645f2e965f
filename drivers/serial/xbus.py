"""Xbus framing of the Xsens MT protocol: checksum, message build, incremental parser.

Pure functions and a byte-stream parser, no I/O. Message layout and checksum rule:
see :mod:`capstan.drivers.serial.xsens_protocol`.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Callable, Mapping

from capstan.drivers.interfaces import LinkStats
from capstan.models.common.errors import ProtocolError

PREAMBLE = 0xFA
BID_MASTER = 0xFF
LEN_EXTENDED = 0xFF
MAX_DATA_LEN = 2048


def checksum(body: bytes | bytearray | memoryview) -> int:
    """Checksum byte for ``body`` = BID..DATA (everything after the preamble but the CS)."""
    return (-sum(body)) & 0xFF


def build_message(mid: int, data: bytes = b"", bid: int = BID_MASTER) -> bytes:
    """Build one complete message (standard or extended length).

    :raises ProtocolError: if ``data`` exceeds 2048 bytes or ``mid`` is not a byte.
    """
    n = len(data)
    if n > MAX_DATA_LEN:
        raise ProtocolError(f"Xbus data too long: {n} > {MAX_DATA_LEN} bytes")
    if not 0 <= mid <= 0xFF:
        raise ProtocolError(f"MID must be one byte, got {mid}")
    if n < LEN_EXTENDED:
        body = bytes((bid, mid, n)) + bytes(data)
    else:
        body = bytes((bid, mid, LEN_EXTENDED, n >> 8, n & 0xFF)) + bytes(data)
    return bytes((PREAMBLE,)) + body + bytes((checksum(body),))


class _Candidate(IntEnum):
    """Verdict on the bytes at one preamble position."""

    INCOMPLETE = 0  # plausible header, the rest has not arrived yet
    IMPOSSIBLE = 1  # length above the bound for its MID (or an invalid extended length)
    BAD_CHECKSUM = 2
    VALID = 3
    MALFORMED = 4  # checksum valid, but the payload fails its MID's structure check


class XbusParser:
    """Incremental Xbus frame parser over an arbitrary byte stream.

    ``feed(data)`` returns the checksum-valid messages as ``(mid, data)`` pairs.

    Length bound: a candidate whose length field exceeds the bound for its MID
    (``limits[mid]``, else ``max_data_len``; the protocol maximum is 2048) is rejected
    as soon as its length field is in, so a corrupt or forged header (e.g.
    ``FA FF 36 FF 07 FF``, extended length 2047) cannot make the parser wait for more
    bytes than the longest frame the configured device can send. A driver sets the
    bound from its output configuration with :meth:`set_limits`.

    Look-ahead: while a candidate is incomplete, the bytes behind its preamble are
    searched for complete checksum-valid frames, which are returned at once; so a
    pending candidate, genuine or not, delays no valid frame behind it. The pending
    candidate is still completed: if it turns out valid it is returned too (after the
    frames found inside it), otherwise it is counted bad and the hunt resumes behind
    the frames already returned. The price is that a genuine frame arriving in pieces
    whose payload happens to contain a complete checksum-valid frame (preamble, bus
    id, plausible length, matching checksum) also yields that inner frame; consumers
    validate the payload (MTData2 item structure) as they do for any frame.

    Accounting in ``stats``: a rejected candidate (impossible length, bad checksum)
    counts one ``bad_frames`` and the hunt resumes one byte after its preamble; each
    loss of sync (garbage or a rejected candidate after a valid frame) counts one
    ``resyncs``; ``bytes_skipped`` counts every byte that belongs to no returned frame.
    ``stats.good_frames`` is left to the consumer.

    Structure checks: the checksum is one byte, so about one in 256 candidates that start
    at a false preamble (inside a truncated frame, say) is checksum-valid by chance and would
    swallow the start of the genuine frame behind it. ``validators[mid]`` (a predicate on the
    data) is applied to every checksum-valid candidate of that MID; one that fails is
    treated like a bad checksum (counted bad, hunt resumes one byte after its preamble), so
    the genuine frame inside it is still found.

    Buffered bytes are bounded by one maximal frame (bound + 7 bytes).

    :param stats: counters to update (a new :class:`LinkStats` if omitted).
    :param bid: bus identifier expected in byte 1 (0xFF for messages to/from the host).
    :param max_data_len: bound on the data length of any MID not in ``limits`` [bytes].
    :param limits: per-MID bound on the data length [bytes].
    :param validators: per-MID structure check of the data (True: well formed).
    :raises ProtocolError: if a bound is outside 0..2048.
    """

    def __init__(self, stats: LinkStats | None = None, bid: int = BID_MASTER,
                 max_data_len: int = MAX_DATA_LEN, limits: Mapping[int, int] | None = None,
                 validators: Mapping[int, Callable[[bytes], bool]] | None = None) -> None:
        self.stats = stats if stats is not None else LinkStats()
        self._validators = dict(validators or {})
        self._buf = bytearray()
        self._sync = bytes((PREAMBLE, bid))
        self._in_sync = False
        self._default_limit = MAX_DATA_LEN
        self._limits: dict[int, int] = {}
        self.set_limits(max_data_len, limits)
        self._ahead_end = 0     # buffer index behind the last frame returned by look-ahead (0: none)
        self._ahead_bytes = 0   # bytes of look-ahead frames still in the buffer
        self._bytes_in = 0
        self._frame_bytes = 0
        self._skipped_reported = 0

    def set_limits(self, max_data_len: int = MAX_DATA_LEN, limits: Mapping[int, int] | None = None) -> None:
        """Bound frame data lengths: ``limits[mid]`` for the MIDs given, else ``max_data_len``.

        :raises ProtocolError: if a bound is outside 0..2048 or a MID is not a byte.
        """
        table = dict(limits or {})
        for mid, lim in [(-1, max_data_len)] + list(table.items()):
            if not 0 <= int(lim) <= MAX_DATA_LEN:
                raise ProtocolError(f"Xbus length bound {lim} for MID {mid} outside 0..{MAX_DATA_LEN}")
            if mid != -1 and not 0 <= mid <= 0xFF:
                raise ProtocolError(f"Xbus length bound for MID {mid}: MID must be one byte")
        self._default_limit = int(max_data_len)
        self._limits = {int(k): int(v) for k, v in table.items()}

    def limit(self, mid: int) -> int:
        """Longest data length accepted for ``mid`` [bytes]."""
        return self._limits.get(mid, self._default_limit)

    def _reject(self) -> None:
        self.stats.bad_frames += 1
        if self._in_sync:
            self.stats.resyncs += 1
        self._in_sync = False

    def reset(self) -> None:
        """Drop buffered bytes (e.g. after reopening the port); they count as skipped."""
        self._buf.clear()
        self._in_sync = False
        self._ahead_end = self._ahead_bytes = 0
        self._report_skipped()

    @property
    def buffered(self) -> int:
        """Bytes waiting for the rest of a frame."""
        return len(self._buf)

    def _report_skipped(self) -> None:
        undecided = len(self._buf) - self._ahead_bytes
        skipped = self._bytes_in - self._frame_bytes - undecided
        self.stats.bytes_skipped += skipped - self._skipped_reported
        self._skipped_reported = skipped

    def _candidate(self, buf: bytearray, j: int, n: int) -> tuple[_Candidate, int, int]:
        """Verdict, header length and end index of the candidate frame at ``buf[j]``."""
        if n - j < 4:
            return _Candidate.INCOMPLETE, 0, 0
        lim = self._limits.get(buf[j + 2], self._default_limit)
        length = buf[j + 3]
        hdr = 4
        if length == LEN_EXTENDED:
            if lim < LEN_EXTENDED:
                return _Candidate.IMPOSSIBLE, 0, 0
            if n - j < 6:
                return _Candidate.INCOMPLETE, 0, 0
            length = (buf[j + 4] << 8) | buf[j + 5]
            hdr = 6
            if length < LEN_EXTENDED:
                return _Candidate.IMPOSSIBLE, 0, 0
        if length > lim:
            return _Candidate.IMPOSSIBLE, 0, 0
        end = j + hdr + length + 1
        if end > n:
            return _Candidate.INCOMPLETE, 0, 0
        if sum(buf[j + 1:end]) & 0xFF:
            return _Candidate.BAD_CHECKSUM, hdr, end
        check = self._validators.get(buf[j + 2])
        if check is not None and not check(bytes(buf[j + hdr:end - 1])):
            return _Candidate.MALFORMED, hdr, end
        return _Candidate.VALID, hdr, end

    def _look_ahead(self, buf: bytearray, j: int, n: int, out: list[tuple[int, bytes]]) -> None:
        """Return the complete valid frames behind the pending candidate at ``j``."""
        p = max(j + 1, self._ahead_end)
        while True:
            k = buf.find(self._sync, p)
            if k < 0:
                return
            verdict, hdr, end = self._candidate(buf, k, n)
            if verdict != _Candidate.VALID:
                p = k + 1
                continue
            out.append((buf[k + 2], bytes(buf[k + hdr:end - 1])))
            self._frame_bytes += end - k
            self._ahead_bytes += end - k
            self._ahead_end = p = end

    def feed(self, data: bytes | bytearray | memoryview) -> list[tuple[int, bytes]]:
        """Add bytes, return all complete checksum-valid messages in arrival order.

        Never raises on malformed input.
        """
        buf = self._buf
        buf += data
        self._bytes_in += len(data)
        out: list[tuple[int, bytes]] = []
        stats = self.stats
        i = 0
        n = len(buf)
        while True:
            j = buf.find(self._sync, i)
            if j < 0:
                # keep a trailing preamble byte, it may be the start of the next frame
                keep = 1 if n > i and buf[n - 1] == PREAMBLE else 0
                if n - keep > i:
                    if self._in_sync:
                        stats.resyncs += 1
                    self._in_sync = False
                i = n - keep
                break
            if j > i:
                if self._in_sync:
                    stats.resyncs += 1
                self._in_sync = False
            verdict, hdr, end = self._candidate(buf, j, n)
            if verdict == _Candidate.INCOMPLETE:
                i = j
                self._look_ahead(buf, j, n, out)
                break
            ahead = self._ahead_end > j
            if verdict == _Candidate.VALID and (not ahead or end >= self._ahead_end):
                out.append((buf[j + 2], bytes(buf[j + hdr:end - 1])))
                self._frame_bytes += end - j - self._ahead_bytes
                self._ahead_end = self._ahead_bytes = 0
                self._in_sync = True
                i = end
                continue
            self._reject()
            i = j + 1
            if ahead:  # resume behind the frames already returned: they are in sync
                i = self._ahead_end
                self._ahead_end = self._ahead_bytes = 0
                self._in_sync = True
        if i:
            del buf[:i]
            if self._ahead_end:
                self._ahead_end -= i
        self._report_skipped()
        return out
