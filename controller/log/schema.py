"""Derive an MCAP (protobuf) schema and a vectorised message codec from a record dtype.

Every scalar field of a flat structured dtype becomes one protobuf field numbered in
dtype order, always present and fixed-width, so each record encodes to the same
number of bytes and encoding/decoding is a numpy view with per-field offsets::

    float64 -> double (fixed64)      float32/16 -> float (fixed32)
    int8..int32 -> sfixed32          uint8..uint32 -> fixed32
    int64 -> sfixed64                uint64 -> fixed64
    bool -> bool (varint, one byte 0/1)

A float64 field can be stored as float32 (``float32_fields``), and such a field
rounded to a power-of-two quantum first (``float32_quanta``, :func:`quantize_float32`):
for display copies of values a replay recomputes, whose low mantissa bits then compress.

The schema is a ``google.protobuf.FileDescriptorSet`` built by hand (no protobuf
package needed), schema encoding ``protobuf``, so Foxglove can decode and plot every
field. Events use JSON with a JSON schema (:data:`EVENT_JSON_SCHEMA`).
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from capstan.models.common.errors import DataFormatError

SCHEMA_ENCODING = "protobuf"
MESSAGE_ENCODING = "protobuf"

# google/protobuf/descriptor.proto: FieldDescriptorProto.Type values
_TYPE_DOUBLE, _TYPE_FLOAT, _TYPE_FIXED64, _TYPE_FIXED32 = 1, 2, 6, 7
_TYPE_BOOL, _TYPE_SFIXED32, _TYPE_SFIXED64 = 8, 15, 16
_LABEL_OPTIONAL = 1
# wire types
_WT_VARINT, _WT_I64, _WT_LEN, _WT_I32 = 0, 1, 2, 5


class LogFormatError(DataFormatError):
    """A dtype cannot be logged, or logged bytes do not match their layout."""


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        b = value & 0x7F
        value >>= 7
        if value:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def _key(number: int, wire_type: int) -> bytes:
    return _varint((number << 3) | wire_type)


def _len_field(number: int, payload: bytes) -> bytes:
    return _key(number, _WT_LEN) + _varint(len(payload)) + payload


def _int_field(number: int, value: int) -> bytes:
    return _key(number, _WT_VARINT) + _varint(value)


def _wire_of(name: str, dt: np.dtype) -> tuple[int, int, str]:
    """(protobuf type, wire type, numpy wire format) for one scalar field."""
    kind, size = dt.kind, dt.itemsize
    if kind == "f" and size == 8:
        return _TYPE_DOUBLE, _WT_I64, "<f8"
    if kind == "f" and size in (2, 4):
        return _TYPE_FLOAT, _WT_I32, "<f4"
    if kind == "i" and size <= 4:
        return _TYPE_SFIXED32, _WT_I32, "<i4"
    if kind == "u" and size <= 4:
        return _TYPE_FIXED32, _WT_I32, "<u4"
    if kind == "i" and size == 8:
        return _TYPE_SFIXED64, _WT_I64, "<i8"
    if kind == "u" and size == 8:
        return _TYPE_FIXED64, _WT_I64, "<u8"
    if kind == "b":
        return _TYPE_BOOL, _WT_VARINT, "u1"
    raise LogFormatError(f"field '{name}': dtype {dt} cannot be logged (scalars only: "
                         "float, int, uint, bool)")


@dataclass(frozen=True)
class ProtoLayout:
    """Codec between a record dtype and fixed-size protobuf messages.

    :ivar dtype: the record dtype.
    :ivar message_name: fully qualified protobuf message name (the MCAP schema name).
    :ivar wire_dtype: dtype viewing one encoded message (fields at their value offsets).
    :ivar template: one encoded message with all values zero (tags in place).
    :ivar schema: serialized FileDescriptorSet.
    """

    dtype: np.dtype
    message_name: str
    wire_dtype: np.dtype
    template: np.ndarray
    schema: bytes
    #: (field, quantum) of float32 fields stored rounded to a multiple of a power of two
    quanta: tuple[tuple[str, float], ...] = ()

    @property
    def message_size(self) -> int:
        """Bytes per encoded message."""
        return int(self.wire_dtype.itemsize)

    def encode(self, records: np.ndarray) -> np.ndarray:
        """Encode ``records`` into an ``(n, message_size)`` uint8 array (row = message)."""
        n = len(records)
        buf = np.empty((n, self.message_size), dtype=np.uint8)
        buf[:] = self.template
        wire = buf.reshape(-1).view(self.wire_dtype)
        for name in self.dtype.names:
            wire[name] = records[name]
        for name, q in self.quanta:
            wire[name] = quantize_float32(records[name], q)
        return buf

    def decode(self, data: bytes | bytearray | memoryview | np.ndarray, check: bool = True) -> np.ndarray:
        """Decode concatenated messages back into records of :attr:`dtype`.

        :param check: verify every message's tag bytes against the template.
        :raises LogFormatError: if the length is not a multiple of the message size or
            (with ``check``) a message does not have this layout.
        """
        raw = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data.reshape(-1)
        if raw.size % self.message_size:
            raise LogFormatError(f"{self.message_name}: {raw.size} bytes is not a multiple of the "
                                 f"message size {self.message_size}")
        rows = raw.reshape(-1, self.message_size)
        if check and rows.shape[0]:
            mask = np.where(self._tag_mask, np.uint8(0xFF), np.uint8(0))
            if ((rows ^ self.template) & mask).any():
                bad = np.any((rows ^ self.template) & mask, axis=1)
                raise LogFormatError(f"{self.message_name}: message {int(np.argmax(bad))} does not "
                                     "match the schema layout")
        byte_map, slow = self._byte_map
        out = np.ascontiguousarray(np.take(rows, byte_map, axis=1)).reshape(-1).view(self.dtype)
        if slow:
            wire = rows.reshape(-1).view(self.wire_dtype)
            for name in slow:
                out[name] = wire[name]
        return out

    def decode_rows(self, rows: np.ndarray, out_dtype: np.dtype | None = None, check: bool = True,
                    out: np.ndarray | None = None) -> np.ndarray:
        """Decode a contiguous ``(n, message_size)`` uint8 array of messages into records
        of ``out_dtype`` (default :attr:`dtype`); see :meth:`decode_span`.

        :raises LogFormatError: on a row size that is not the message size, or (with
            ``check``) a message whose tag bytes differ from the layout.
        """
        if rows.ndim != 2 or rows.shape[1] != self.message_size:
            raise LogFormatError(f"{self.message_name}: rows of {rows.shape[-1]} bytes, messages have "
                                 f"{self.message_size}")
        flat = np.ascontiguousarray(rows).reshape(-1)
        return self.decode_span(flat, 0, len(rows), self.message_size, out_dtype, check, out)

    def decode_span(self, buf: np.ndarray, offset: int, n: int, stride: int, out_dtype: np.dtype | None = None,
                    check: bool = True, out: np.ndarray | None = None) -> np.ndarray:
        """Decode ``n`` messages at ``buf[offset + k * stride]`` (a chunk's bytes, read in
        place) into records of ``out_dtype`` (default :attr:`dtype`). Fields of
        ``out_dtype`` the messages do not carry are left unset (the caller fills them);
        ``out``: a contiguous array of ``n`` records to decode into.

        :raises LogFormatError: if (with ``check``) a message's tag bytes differ from the layout.
        """
        out_dtype = self.dtype if out_dtype is None else np.dtype(out_dtype)
        if out is None:
            out = np.empty(n, out_dtype)
        if not n:
            return out
        if check:
            rows = np.ndarray((n, self.message_size), np.uint8, buffer=buf, offset=offset, strides=(stride, 1))
            tags = self.__dict__.get("_tags")
            if tags is None:
                tags = np.flatnonzero(self._tag_mask)
                object.__setattr__(self, "_tags", tags)
            bad = (np.take(rows, tags, axis=1) != self.template[tags]).any(axis=1)
            if bad.any():
                raise LogFormatError(f"{self.message_name}: message {int(np.argmax(bad))} does not "
                                     "match the schema layout")
        # the messages as a structured array over the bytes (each field a typed, strided
        # view; numpy converts float32 -> float64 and narrows integers exactly)
        wire = np.ndarray((n,), self.wire_dtype, buffer=buf, offset=offset, strides=(stride,))
        for name in out_dtype.names:
            if name in self.wire_dtype.names:
                out[name] = wire[name]
        return out

    def _map_for(self, out_dtype: np.dtype) -> tuple[np.ndarray, tuple[str, ...]]:
        """Byte map and value-converted fields for decoding into ``out_dtype``."""
        cache = self.__dict__.setdefault("_map_cache", {})
        if out_dtype in cache:
            return cache[out_dtype]
        bmap = np.zeros(out_dtype.itemsize, dtype=np.intp)
        slow = []
        for name in out_dtype.names:
            if name not in self.wire_dtype.names:
                continue
            fdt, off = out_dtype.fields[name][:2]
            wdt, woff = self.wire_dtype.fields[name][:2]
            same_kind = fdt.kind == wdt.kind or (fdt.kind == "b" and wdt.kind == "u")
            little = fdt.byteorder in ("<", "|") or (fdt.byteorder == "=" and sys.byteorder == "little")
            if (same_kind and little and fdt.kind != "f" and fdt.itemsize <= wdt.itemsize) or fdt == wdt:
                bmap[off:off + fdt.itemsize] = np.arange(woff, woff + fdt.itemsize)
            else:
                slow.append(name)
        cache[out_dtype] = (bmap, tuple(slow))
        return cache[out_dtype]

    @property
    def _byte_map(self) -> tuple[np.ndarray, tuple[str, ...]]:
        """For each byte of a record, the message byte it comes from, plus the fields that
        need a value conversion (float16, float32 storage of float64, big-endian)."""
        cached = self.__dict__.get("_byte_map_cache")
        if cached is not None:
            return cached
        byte_map = np.zeros(self.dtype.itemsize, dtype=np.intp)
        slow = []
        for name in self.dtype.names:
            fdt, off = self.dtype.fields[name][:2]
            wdt, woff = self.wire_dtype.fields[name][:2]
            same_kind = fdt.kind == wdt.kind or (fdt.kind == "b" and wdt.kind == "u")
            little = fdt.byteorder in ("<", "|") or (fdt.byteorder == "=" and sys.byteorder == "little")
            if same_kind and little and fdt.kind != "f" or (fdt == wdt):
                # little-endian integers narrow by dropping high bytes; equal types copy
                byte_map[off:off + fdt.itemsize] = np.arange(woff, woff + fdt.itemsize)
            else:
                slow.append(name)
        result = (byte_map, tuple(slow))
        object.__setattr__(self, "_byte_map_cache", result)
        return result

    @property
    def _tag_mask(self) -> np.ndarray:
        mask = np.ones(self.message_size, dtype=bool)
        for name in self.wire_dtype.names:
            fdt, off = self.wire_dtype.fields[name][:2]
            mask[off:off + fdt.itemsize] = False
        return mask


def check_quantum(name: str, quantum: float) -> float:
    """``quantum`` as a float if it is a power of two (2**k, any integer k).

    :raises LogFormatError: naming the field, if it is not finite, positive and a power of two.
    """
    try:
        q = float(quantum)
    except (TypeError, ValueError):
        raise LogFormatError(f"float32 quantum of '{name}': {quantum!r} is not a number") from None
    if not (math.isfinite(q) and q > 0 and math.frexp(q)[0] == 0.5):
        raise LogFormatError(f"float32 quantum of '{name}': {quantum!r} is not a power of two "
                             "(2**k; only those leave the low mantissa bits zero)")
    return q


def quantize_float32(values: np.ndarray, quantum: float) -> np.ndarray:
    """``values`` rounded to the nearest multiple of ``quantum`` (a power of two, ties
    to even), as float32. Exact below ``2**24 * quantum`` in magnitude (the multiple is
    a float32; above that float32 rounding applies); NaN and infinities pass unchanged.
    Division and multiplication by a power of two are exact, so the result depends only
    on the value: a reader that applies it to a recomputed value gets the stored bits.
    """
    x = np.asarray(values, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        return (np.round(x / quantum) * quantum).astype(np.float32)


def build_layout(dtype: np.dtype, message_name: str = "capstan.Cycle",
                 float32_fields: tuple[str, ...] = (),
                 float32_quanta: Mapping[str, float] | None = None) -> ProtoLayout:
    """Build the protobuf codec and FileDescriptorSet for a flat structured dtype.

    :param message_name: ``package.Message``; the package part may be empty.
    :param float32_fields: float64 fields stored as protobuf ``float`` (lossy: rounded
        to float32, about 7 significant digits; decoded back to float64). Use it for
        values that are recomputed on replay, never for replay inputs or the command.
    :param float32_quanta: float32 field -> quantum (a power of two, in the field's
        unit): the field is stored rounded to a multiple of it
        (:func:`quantize_float32`), which leaves the low mantissa bits zero so the
        values compress; for display copies of values a replay recomputes.
    :raises LogFormatError: if the dtype is not structured, has nested/array fields or
        a field type that cannot be logged, a float32 field is unknown / not float64, or
        a quantum names a field that is not a float32 field or is not a power of two.
    """
    dtype = np.dtype(dtype)
    if dtype.names is None:
        raise LogFormatError(f"record dtype must be structured, got {dtype}")
    for name in float32_fields:
        if name not in dtype.names or dtype.fields[name][0] != np.float64:
            raise LogFormatError(f"float32 field '{name}': not a float64 field of the record")
    quanta = []
    for name, q in (float32_quanta or {}).items():
        if name not in float32_fields:
            raise LogFormatError(f"float32 quantum of '{name}': not one of the float32 fields")
        quanta.append((name, check_quantum(name, q)))
    package, _, short = message_name.rpartition(".")
    names, formats, offsets, fields_desc = [], [], [], b""
    template = bytearray()
    for number, name in enumerate(dtype.names, start=1):
        fdt = dtype.fields[name][0]
        if fdt.shape != () or fdt.names is not None:
            raise LogFormatError(f"field '{name}': nested or array fields cannot be logged ({fdt})")
        ptype, wtype, wfmt = _wire_of(name, fdt)
        if name in float32_fields:
            ptype, wtype, wfmt = _TYPE_FLOAT, _WT_I32, "<f4"
        template += _key(number, wtype)
        names.append(name)
        formats.append(wfmt)
        offsets.append(len(template))
        template += b"\0" * np.dtype(wfmt).itemsize
        fields_desc += _len_field(2, _len_field(1, name.encode()) + _int_field(3, number)
                                  + _int_field(4, _LABEL_OPTIONAL) + _int_field(5, ptype)
                                  + _len_field(10, name.encode()))
    wire_dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets,
                           "itemsize": len(template)})
    message = _len_field(1, short.encode()) + fields_desc
    file_proto = (_len_field(1, f"{message_name.replace('.', '/')}.proto".encode())
                  + (_len_field(2, package.encode()) if package else b"")
                  + _len_field(4, message) + _len_field(12, b"proto3"))
    schema = _len_field(1, file_proto)
    return ProtoLayout(dtype, message_name, wire_dtype,
                       np.frombuffer(bytes(template), dtype=np.uint8).copy(), schema, tuple(quanta))


#: JSON schema of the ``/capstan/events`` channel (faults, drops, writer notices)
EVENT_JSON_SCHEMA: dict = {
    "title": "capstan.Event",
    "type": "object",
    "properties": {
        "t_s": {"type": "number", "description": "monotonic time of the event [s]"},
        "kind": {"type": "integer", "description": "EventKind value"},
        "kind_name": {"type": "string"},
        "code": {"type": "integer", "description": "fault bits / event code"},
        "reason": {"type": "string"},
        "dropped_total": {"type": "integer", "description": "records dropped so far"},
        "gap_cycles": {"type": "integer",
                       "description": "WRITER_RESTARTED: cycles missing before this file's first record"},
        "gap_first_cycle": {"type": "integer", "description": "first missing cycle number"},
        "gap_last_cycle": {"type": "integer", "description": "last missing cycle number"},
        "last_cycles": {"type": "object",
                        "description": "field name -> list of values of the last N cycles"},
    },
    "required": ["t_s", "kind", "kind_name"],
}


def event_schema_bytes() -> bytes:
    """Serialized :data:`EVENT_JSON_SCHEMA`."""
    return json.dumps(EVENT_JSON_SCHEMA).encode()
