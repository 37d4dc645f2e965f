"""Expedited SDO server of the peer drive (CiA 301 §7.2.4.3), written from the specification.

Only expedited transfers (objects of at most 4 bytes); anything else is aborted with
"command specifier not valid". Abort codes are those of CiA 301 table 22.
"""

from __future__ import annotations

import struct
from typing import Callable

from cia402_peer.od import Entry

ABORT_COMMAND = 0x05040001
ABORT_READ_ONLY = 0x06010002
ABORT_WRITE_ONLY = 0x06010001
ABORT_NO_OBJECT = 0x06020000
ABORT_LENGTH = 0x06070010
ABORT_NO_SUB = 0x06090011
ABORT_RANGE = 0x06090030
ABORT_STATE = 0x08000022
ABORT_GENERAL = 0x08000000


class SdoAbort(Exception):
    """Raised by a write/read hook to abort the transfer with ``code``."""

    def __init__(self, code: int) -> None:
        super().__init__(f"0x{code:08X}")
        self.code = code


def abort_frame(index: int, sub: int, code: int) -> bytes:
    return struct.pack("<BHBI", 0x80, index, sub, code)


def handle_request(data: bytes, od: dict[tuple[int, int], Entry],
                   read: Callable[[Entry], int], write: Callable[[Entry, int], None]) -> bytes | None:
    """The response frame to one SDO request (8 bytes); None for an abort request (no answer)."""
    data = bytes(data).ljust(8, b"\x00")
    ccs = data[0] >> 5
    index, sub = struct.unpack_from("<HB", data, 1)
    if ccs == 4:
        return None
    if ccs not in (1, 2):
        return abort_frame(index, sub, ABORT_COMMAND)
    entry = od.get((index, sub))
    if entry is None:
        exists = any(i == index for i, _ in od)
        return abort_frame(index, sub, ABORT_NO_SUB if exists else ABORT_NO_OBJECT)
    try:
        if ccs == 2:  # initiate upload
            if not entry.readable:
                raise SdoAbort(ABORT_WRITE_ONLY)
            payload = entry.encode(read(entry))
            n = len(payload)
            return bytes([0x43 | ((4 - n) << 2), index & 0xFF, index >> 8, sub]) + payload.ljust(4, b"\x00")
        # initiate download: expedited only
        if not data[0] & 0x02:
            raise SdoAbort(ABORT_COMMAND)
        n = 4 - ((data[0] >> 2) & 0x3) if data[0] & 0x01 else 4
        if not entry.writable:
            raise SdoAbort(ABORT_READ_ONLY)
        if data[0] & 0x01 and n != entry.size:
            raise SdoAbort(ABORT_LENGTH)
        write(entry, entry.decode(data[4:4 + n]))
        return bytes([0x60, index & 0xFF, index >> 8, sub, 0, 0, 0, 0])
    except SdoAbort as exc:
        return abort_frame(index, sub, exc.code)
