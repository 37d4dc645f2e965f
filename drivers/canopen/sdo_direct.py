"""Expedited SDO frames built and parsed by hand (CiA 301 §7.2.4.3), for use without a receive thread.

After start-up :class:`~capstan.drivers.canopen.motor.CanopenMotor` reads the bus itself
(no canopen notifier thread), so canopen's SDO client, which waits on that thread, cannot
be used. The few SDO transfers needed then (statusword, mode display, disarming the
consumer heartbeat) are single expedited frames: :func:`request` builds one,
:func:`parse_reply` checks the answer and names index:sub-index and the abort text.
"""

from __future__ import annotations

import canopen
from canopen.objectdictionary import ODVariable

from capstan.drivers.canopen.sdo_access import SdoRefusedError
from capstan.models.common.errors import ProtocolError

__all__ = ["request", "parse_reply"]


def request(var: ODVariable, value: int | None = None) -> bytes:
    """Initiate-upload (``value`` None) or expedited initiate-download frame for ``var``.

    :raises ProtocolError: if the object is longer than 4 bytes (not expedited).
    """
    index, sub = var.index, var.subindex
    head = bytes([index & 0xFF, index >> 8, sub])
    if value is None:
        return bytes([0x40]) + head + bytes(4)
    payload = var.encode_raw(value)
    if not 1 <= len(payload) <= 4:
        raise ProtocolError(f"0x{index:04X}:{sub:02X} has {len(payload)} bytes; expedited SDO holds 1..4")
    return bytes([0x23 | ((4 - len(payload)) << 2)]) + head + payload.ljust(4, b"\x00")


def parse_reply(var: ODVariable, reply: bytes, node_id: int, upload: bool) -> int | None:
    """The value of an upload reply (None for a download confirmation).

    :raises SdoRefusedError: on an abort frame (index:sub-index, code and CiA 301 text).
    :raises ProtocolError: on a reply for another object or an unexpected command.
    """
    where = f"drive {node_id}: SDO {'read' if upload else 'write'} 0x{var.index:04X}:{var.subindex:02X}"
    if len(reply) < 8:
        raise ProtocolError(f"{where}: short reply {bytes(reply).hex()}")
    index, sub = reply[1] | reply[2] << 8, reply[3]
    if (index, sub) != (var.index, var.subindex):
        raise ProtocolError(f"{where}: reply names 0x{index:04X}:{sub:02X}")
    if reply[0] == 0x80:
        code = int.from_bytes(reply[4:8], "little")
        text = canopen.SdoAbortedError.CODES.get(code, "unknown abort code")
        raise SdoRefusedError(f"{where} refused: abort 0x{code:08X} ({text})", code)
    if not upload:
        if reply[0] != 0x60:
            raise ProtocolError(f"{where}: unexpected reply {bytes(reply).hex()}")
        return None
    if reply[0] & 0xE2 != 0x42:
        raise ProtocolError(f"{where}: not an expedited upload reply {bytes(reply).hex()}")
    n = 4 - ((reply[0] >> 2) & 0x3) if reply[0] & 0x01 else len(var.encode_raw(0))
    return int(var.decode_raw(bytes(reply[4:4 + n])))
