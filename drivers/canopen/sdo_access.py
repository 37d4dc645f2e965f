"""SDO reads and writes whose errors name the object: ``drive 3: SDO write 0x6072:00 = 300 refused ...``.

Thin wrappers around canopen's SDO client (expedited and segmented transfers, retries
and abort handling stay canopen's): a refusal (SDO abort) becomes a
:class:`~capstan.models.common.errors.DriverError` naming index:sub-index, the value, the
abort code and its CiA 301 text; no answer becomes a
:class:`~capstan.models.common.errors.DeviceTimeoutError` naming the object.
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

import canopen
from canopen.objectdictionary import ODVariable

from capstan.models.common.errors import DeviceTimeoutError, DriverError

__all__ = ["SdoRefusedError", "sdo_read", "sdo_write", "has_object"]


class SdoRefusedError(DriverError):
    """The drive aborted an SDO transfer; :attr:`abort_code` holds the CiA 301 abort code."""

    def __init__(self, text: str, abort_code: int) -> None:
        super().__init__(text)
        self.abort_code = abort_code


def has_object(node: canopen.RemoteNode, index: int, sub: int = 0) -> bool:
    """True if the node's object dictionary (its EDS) lists ``index:sub``."""
    od = node.object_dictionary
    if index not in od:
        return False
    obj = od[index]
    return sub == 0 if isinstance(obj, ODVariable) else sub in obj


def _variable(node: canopen.RemoteNode, index: int, sub: int) -> canopen.sdo.base.SdoVariable:
    obj = node.sdo[index]
    return obj if isinstance(node.object_dictionary[index], ODVariable) else obj[sub]


@contextmanager
def _translated(node: canopen.RemoteNode, index: int, sub: int, where: str) -> Iterator[canopen.sdo.base.SdoVariable]:
    """The SDO variable ``index:sub``, with the canopen errors of its transfer raised as the
    project's (``where`` names the access in every message)."""
    if not has_object(node, index, sub):
        raise DriverError(f"{where}: the EDS does not list this object")
    try:
        yield _variable(node, index, sub)
    except canopen.SdoAbortedError as exc:
        raise SdoRefusedError(f"{where} refused: abort 0x{exc.code:08X} "
                              f"({exc.CODES.get(exc.code, 'unknown abort code')})", exc.code) from exc
    except canopen.SdoCommunicationError as exc:
        raise DeviceTimeoutError(f"{where}: no answer ({exc})") from exc


def sdo_read(node: canopen.RemoteNode, index: int, sub: int = 0) -> int:
    """Value of ``index:sub`` read over SDO (integer objects).

    :raises SdoRefusedError: if the drive aborts the upload (index:sub, code and text named).
    :raises DeviceTimeoutError: if the drive does not answer.
    :raises DriverError: if the EDS does not list the object.
    """
    where = f"drive {node.id}: SDO read 0x{index:04X}:{sub:02X}"
    with _translated(node, index, sub, where) as var:
        return int(var.raw)


def sdo_write(node: canopen.RemoteNode, index: int, sub: int, value: int) -> None:
    """Write ``value`` to ``index:sub`` over SDO.

    :raises SdoRefusedError: if the drive aborts the download (index:sub, value, code and text).
    :raises DeviceTimeoutError: if the drive does not answer.
    :raises DriverError: if the EDS does not list the object.
    """
    where = f"drive {node.id}: SDO write 0x{index:04X}:{sub:02X} = {value} (0x{value & 0xFFFFFFFF:X})"
    with _translated(node, index, sub, where) as var:
        var.raw = value
