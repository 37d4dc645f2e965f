"""Xsens MT binary protocol: message identifiers, MTData2 decoding, number formats.

Pure functions, no I/O. Follows the Xsens *MT Low-Level Communication Protocol*
documentation. The framing (:mod:`capstan.drivers.serial.xbus`: checksum, message build, stream
parser) is re-exported here.

Message layout (standard length, 0..254 data bytes)::

    FA | BID=FF | MID | LEN | DATA[LEN] | CS

Extended length (255..2048 data bytes): ``LEN = 0xFF`` followed by a big-endian
uint16 ``EXT_LEN``::

    FA | FF | MID | FF | EXT_HI | EXT_LO | DATA[EXT_LEN] | CS

Checksum: all bytes after the preamble (BID, MID, LEN[, EXT], DATA, CS) sum to 0
modulo 256, i.e. ``CS = (-sum(BID..DATA)) & 0xFF``. Example: GoToConfig is
``FA FF 30 00 D1``.

MTData2 (MID 0x36) data is a sequence of items ``XDI (uint16 BE) | SIZE (uint8) |
VALUE[SIZE]``. The low nibble of the XDI is the data format: bits 0x0003 the
precision (0 float32, 1 fp12.20, 2 fp16.32, 3 float64) and bits 0x000C the
coordinate system (0 ENU, 4 NED, 8 NWU). All values are big-endian. fp12.20 is a
signed int32 ``round(x * 2**20)``; fp16.32 is the low 48 bits of the int64
``round(x * 2**32)`` sent as the 32-bit fractional part first, then the 16-bit
integer part (each big-endian), 6 bytes in total.

Units as sent by the device: quaternion (q0=w, q1, q2, q3) unitless; Euler angles
(roll, pitch, yaw) in degrees; rate of turn in rad/s (sensor frame); SampleTimeFine
in ticks of 100 µs (10 kHz); PacketCounter uint16 wrapping at 65536.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

from capstan.drivers.serial.xbus import (  # noqa: F401  (framing re-exported: one import for users)
    BID_MASTER, LEN_EXTENDED, MAX_DATA_LEN, PREAMBLE, XbusParser, build_message, checksum,
)
from capstan.models.common.errors import ProtocolError

SAMPLE_TIME_FINE_HZ = 10_000
#: frequency value meaning "every packet / maximum" in an output configuration
FREQ_EVERY_PACKET = 0xFFFF


class Mid(IntEnum):
    """Message identifiers used by capstan."""

    REQ_DID = 0x00
    DEVICE_ID = 0x01
    INIT_MT = 0x02
    INIT_MT_RESULTS = 0x03
    REQ_CONFIGURATION = 0x0C
    CONFIGURATION = 0x0D
    GO_TO_MEASUREMENT = 0x10
    GO_TO_MEASUREMENT_ACK = 0x11
    REQ_FW_REV = 0x12
    FIRMWARE_REV = 0x13
    GO_TO_CONFIG = 0x30
    GO_TO_CONFIG_ACK = 0x31
    MT_DATA2 = 0x36
    WAKE_UP = 0x3E
    WAKE_UP_ACK = 0x3F
    ERROR = 0x42
    SET_OUTPUT_CONFIGURATION = 0xC0
    OUTPUT_CONFIGURATION = 0xC1


class Xdi(IntEnum):
    """XDI data identifiers (type part, format nibble zero)."""

    TEMPERATURE = 0x0810
    PACKET_COUNTER = 0x1020
    SAMPLE_TIME_FINE = 0x1060
    QUATERNION = 0x2010
    ROTATION_MATRIX = 0x2020
    EULER_ANGLES = 0x2030
    BARO_PRESSURE = 0x3010
    DELTA_V = 0x4010
    ACCELERATION = 0x4020
    FREE_ACCELERATION = 0x4030
    RATE_OF_TURN = 0x8020
    DELTA_Q = 0x8030
    MAGNETIC_FIELD = 0xC020
    STATUS_BYTE = 0xE010
    STATUS_WORD = 0xE020


class Precision(IntEnum):
    """Format bits 0x0003 of an XDI."""

    FLOAT32 = 0
    FP1220 = 1
    FP1632 = 2
    FLOAT64 = 3


class CoordSys(IntEnum):
    """Format bits 0x000C of an XDI."""

    ENU = 0x0
    NED = 0x4
    NWU = 0x8


class ErrorCode(IntEnum):
    """Payload byte of an Error (0x42) message (subset)."""

    NO_BUS = 1
    BUS_NOT_READY = 2
    INVALID_PERIOD = 3
    INVALID_MESSAGE = 4
    TIMER_OVERFLOW = 30
    BAUDRATE_INVALID = 32
    INVALID_PARAM = 33
    DEVICE_ERROR = 40
    DATA_OVERFLOW = 41
    BUFFER_OVERFLOW = 42


XDI_TYPE_MASK = 0xFFF0
PRECISION_MASK = 0x0003
COORD_MASK = 0x000C

#: number of real values of each floating-point item type
_FLOAT_COUNTS: dict[int, int] = {
    Xdi.TEMPERATURE: 1, Xdi.QUATERNION: 4, Xdi.ROTATION_MATRIX: 9, Xdi.EULER_ANGLES: 3,
    Xdi.DELTA_V: 3, Xdi.ACCELERATION: 3, Xdi.FREE_ACCELERATION: 3, Xdi.RATE_OF_TURN: 3,
    Xdi.DELTA_Q: 4, Xdi.MAGNETIC_FIELD: 3,
}
#: integer item types -> struct format
_INT_FORMATS: dict[int, str] = {
    Xdi.PACKET_COUNTER: ">H", Xdi.SAMPLE_TIME_FINE: ">I", Xdi.BARO_PRESSURE: ">I",
    Xdi.STATUS_BYTE: ">B", Xdi.STATUS_WORD: ">I",
}
_WIDTH = {Precision.FLOAT32: 4, Precision.FP1220: 4, Precision.FP1632: 6, Precision.FLOAT64: 8}
_ITEM_HDR = struct.Struct(">HB")


# --------------------------------------------------------------------------- numbers

def encode_values(values: tuple[float, ...] | list[float], precision: int) -> bytes:
    """Encode real values in one of the four MTData2 number formats (big-endian).

    :raises ProtocolError: if a fixed-point value is out of range or precision unknown.
    """
    p = Precision(precision)
    if p == Precision.FLOAT32:
        return struct.pack(f">{len(values)}f", *values)
    if p == Precision.FLOAT64:
        return struct.pack(f">{len(values)}d", *values)
    out = bytearray()
    for v in values:
        if p == Precision.FP1220:
            k = round(v * (1 << 20))
            if not -(1 << 31) <= k < (1 << 31):
                raise ProtocolError(f"value {v} out of fp12.20 range")
            out += struct.pack(">i", k)
        else:
            k = round(v * (1 << 32))
            if not -(1 << 47) <= k < (1 << 47):
                raise ProtocolError(f"value {v} out of fp16.32 range")
            k &= (1 << 48) - 1
            out += struct.pack(">IH", k & 0xFFFFFFFF, k >> 32)
    return bytes(out)


def decode_values(raw: bytes | memoryview, precision: int) -> tuple[float, ...]:
    """Decode a run of MTData2 reals in the given precision.

    :raises ProtocolError: if the size is not a multiple of the element width.
    """
    p = Precision(precision & PRECISION_MASK)
    width = _WIDTH[p]
    n, rem = divmod(len(raw), width)
    if rem:
        raise ProtocolError(f"{len(raw)} bytes is not a multiple of {width} ({p.name})")
    if p == Precision.FLOAT32:
        return struct.unpack(f">{n}f", raw)
    if p == Precision.FLOAT64:
        return struct.unpack(f">{n}d", raw)
    if p == Precision.FP1220:
        return tuple(k / 1048576.0 for k in struct.unpack(f">{n}i", raw))
    vals = []
    for frac, ipart in struct.iter_unpack(">Ih", raw):
        vals.append(((ipart << 32) | frac) / 4294967296.0)
    return tuple(vals)


# --------------------------------------------------------------------------- MTData2

@dataclass(slots=True)
class MtData2:
    """Decoded content of one MTData2 message (``None`` = item absent).

    :ivar packet_counter: PacketCounter (uint16, wraps).
    :ivar sample_time_fine: SampleTimeFine [ticks of 100 µs].
    :ivar quaternion: (q0, q1, q2, q3), q0 the scalar part.
    :ivar euler_deg: (roll, pitch, yaw) [deg].
    :ivar rate_of_turn_rad_s: (x, y, z) in the sensor frame [rad/s].
    :ivar status_word: StatusWord bit field.
    :ivar coord_sys: coordinate system bits of the orientation item (0 ENU, 4 NED, 8 NWU).
    :ivar other: every other item, XDI -> decoded values (ints, floats) or raw bytes.
    """

    packet_counter: int | None = None
    sample_time_fine: int | None = None
    quaternion: tuple[float, ...] | None = None
    euler_deg: tuple[float, ...] | None = None
    rate_of_turn_rad_s: tuple[float, ...] | None = None
    status_word: int | None = None
    coord_sys: int | None = None
    other: dict[int, object] = field(default_factory=dict)


_SLOTS = {Xdi.QUATERNION: "quaternion", Xdi.EULER_ANGLES: "euler_deg",
          Xdi.RATE_OF_TURN: "rate_of_turn_rad_s", Xdi.PACKET_COUNTER: "packet_counter",
          Xdi.SAMPLE_TIME_FINE: "sample_time_fine", Xdi.STATUS_WORD: "status_word"}
#: full XDI -> (MtData2 attribute or None for ``other``, value size, decoder); built lazily
_DECODERS: dict[int, tuple[str | None, int, Any]] = {}


def _unpack_first(st: struct.Struct) -> Any:
    return lambda raw: st.unpack(raw)[0]


def _item_decoder(xdi: int) -> tuple[str | None, int, Any] | None:
    dec = _DECODERS.get(xdi)
    if dec is not None:
        return dec
    kind = xdi & XDI_TYPE_MASK
    if kind in _FLOAT_COUNTS:
        count = _FLOAT_COUNTS[kind]
        prec = Precision(xdi & PRECISION_MASK)
        if prec == Precision.FLOAT32:
            fn = struct.Struct(f">{count}f").unpack
        elif prec == Precision.FLOAT64:
            fn = struct.Struct(f">{count}d").unpack
        else:
            fn = lambda raw, p=prec: decode_values(raw, p)  # noqa: E731
        dec = (_SLOTS.get(kind), count * _WIDTH[prec], fn)
    elif kind in _INT_FORMATS:
        st = struct.Struct(_INT_FORMATS[kind])
        dec = (_SLOTS.get(kind), st.size, _unpack_first(st))
    else:
        return None
    _DECODERS[xdi] = dec
    return dec


def item_value_size(xdi: int) -> int | None:
    """Value bytes of one MTData2 item with this XDI, None for an XDI capstan does not know."""
    dec = _DECODERS.get(xdi) or _item_decoder(xdi)
    return None if dec is None else dec[1]


def mtdata2_max_len(items: list[tuple[int, int]]) -> int:
    """Longest MTData2 data [bytes] an output configuration can produce (all items present).

    :raises ProtocolError: if an item's size is unknown (the bound would be a guess).
    """
    total = 0
    for xdi, _freq in items:
        size = item_value_size(xdi)
        if size is None:
            raise ProtocolError(f"size of MTData2 item 0x{xdi:04X} ({xdi_name(xdi)}) is unknown")
        total += 3 + size
    return total


def mtdata2_well_formed(data: bytes) -> bool:
    """True if the MTData2 items (2-byte XDI, 1-byte size, data) exactly cover ``data``.

    The structure check the Xbus parser applies before it accepts a checksum-valid frame.
    """
    i, n = 0, len(data)
    while n - i >= 3:
        i += 3 + data[i + 2]
    return i == n


def parse_mtdata2(data: bytes) -> MtData2:
    """Decode the data of one MTData2 message.

    :raises ProtocolError: if an item overruns the message or has the wrong size.
    """
    out = MtData2()
    i = 0
    n = len(data)
    unpack_hdr = _ITEM_HDR.unpack_from
    while i < n:
        if n - i < 3:
            raise ProtocolError(f"MTData2: {n - i} trailing bytes, item header needs 3")
        xdi, size = unpack_hdr(data, i)
        i += 3
        if i + size > n:
            raise ProtocolError(f"MTData2: item 0x{xdi:04X} of {size} bytes overruns message")
        raw = data[i:i + size]
        i += size
        dec = _DECODERS.get(xdi) or _item_decoder(xdi)
        if dec is None:
            out.other[xdi] = raw
            continue
        slot, want, fn = dec
        if size != want:
            raise ProtocolError(f"MTData2: XDI 0x{xdi:04X} has {size} bytes, expected {want}")
        val = fn(raw)
        if slot is None:
            out.other[xdi] = val
        else:
            setattr(out, slot, val)
            if slot == "quaternion" or slot == "euler_deg":
                out.coord_sys = xdi & COORD_MASK
    return out


def build_mtdata2_item(xdi: int, value: bytes) -> bytes:
    """One MTData2 item: XDI, size byte, value bytes.

    :raises ProtocolError: if the value is longer than 255 bytes.
    """
    if len(value) > 255:
        raise ProtocolError(f"MTData2 item 0x{xdi:04X} too long: {len(value)} bytes")
    return _ITEM_HDR.pack(xdi, len(value)) + value


# --------------------------------------------------------------------------- configuration

def encode_output_configuration(items: list[tuple[int, int]]) -> bytes:
    """Data of SetOutputConfiguration: (XDI, frequency_hz) pairs, 4 bytes each."""
    return b"".join(struct.pack(">HH", xdi, freq) for xdi, freq in items)


def decode_output_configuration(data: bytes) -> list[tuple[int, int]]:
    """Inverse of :func:`encode_output_configuration`.

    :raises ProtocolError: if the length is not a multiple of 4.
    """
    if len(data) % 4:
        raise ProtocolError(f"output configuration of {len(data)} bytes is not a multiple of 4")
    return [tuple(p) for p in struct.iter_unpack(">HH", data)]  # type: ignore[misc]


def error_name(code: int) -> str:
    """Readable name of an Error (0x42) code."""
    try:
        return ErrorCode(code).name
    except ValueError:
        return f"UNKNOWN_{code}"


def xdi_name(xdi: int) -> str:
    """Readable name of an XDI including its format, e.g. ``QUATERNION|FP1632|NED``."""
    kind = xdi & XDI_TYPE_MASK
    try:
        name = Xdi(kind).name
    except ValueError:
        return f"XDI_0x{xdi:04X}"
    if kind in _FLOAT_COUNTS:
        name += "|" + Precision(xdi & PRECISION_MASK).name
        if kind in (Xdi.QUATERNION, Xdi.EULER_ANGLES, Xdi.ROTATION_MATRIX):
            try:
                name += "|" + CoordSys(xdi & COORD_MASK).name
            except ValueError:
                name += f"|COORD_{xdi & COORD_MASK:X}"
    return name
