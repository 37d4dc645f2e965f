"""Xbus framing of the Xsens MT protocol: checksum, message build, incremental parser.

Pure functions and a byte-stream parser, no I/O. Message layout and checksum rule:
see :mod:`capstan.drivers.serial.xsens_protocol`.
"""

from __future__ import annotations

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


class XbusParser:
    """Incremental Xbus frame parser over an arbitrary byte stream.

    ``feed(data)`` returns the checksum-valid messages as ``(mid, data)`` pairs. Garbage
    between frames is skipped; a candidate frame with a bad checksum or an impossible
    extended length is counted in ``stats.bad_frames`` and the hunt resumes one byte
    after its preamble (each loss of sync, by garbage or a bad frame, counts one
    resync), so
    a truncated frame never swallows the valid frame behind it. ``stats.good_frames`` is
    left to the consumer (it may still reject a checksum-valid but malformed payload).

    Buffered bytes are bounded by one maximal frame (2055 bytes).

    :param stats: counters to update (a new :class:`LinkStats` if omitted).
    :param bid: bus identifier expected in byte 1 (0xFF for messages to/from the host).
    """

    def __init__(self, stats: LinkStats | None = None, bid: int = BID_MASTER) -> None:
        self.stats = stats if stats is not None else LinkStats()
        self._buf = bytearray()
        self._sync = bytes((PREAMBLE, bid))
        self._in_sync = False

    def _reject(self) -> None:
        self.stats.bad_frames += 1
        if self._in_sync:
            self.stats.resyncs += 1
        self._in_sync = False

    def reset(self) -> None:
        """Drop buffered bytes (e.g. after reopening the port)."""
        self._buf.clear()
        self._in_sync = False

    @property
    def buffered(self) -> int:
        """Bytes waiting for the rest of a frame."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[tuple[int, bytes]]:
        """Add bytes, return all complete checksum-valid messages in arrival order.

        Never raises on malformed input.
        """
        buf = self._buf
        buf += data
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
            if n - j < 4:
                i = j
                break
            length = buf[j + 3]
            hdr = 4
            if length == LEN_EXTENDED:
                if n - j < 6:
                    i = j
                    break
                length = (buf[j + 4] << 8) | buf[j + 5]
                hdr = 6
                if length < LEN_EXTENDED or length > MAX_DATA_LEN:
                    self._reject()
                    i = j + 1
                    continue
            end = j + hdr + length + 1
            if end > n:
                i = j
                break
            if sum(buf[j + 1:end]) & 0xFF:
                self._reject()
                i = j + 1
                continue
            out.append((buf[j + 2], bytes(buf[j + hdr:end - 1])))
            self._in_sync = True
            i = end
        if i:
            del buf[:i]
        return out
