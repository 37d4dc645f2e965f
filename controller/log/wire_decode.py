"""Compiled decoding of a chunk's cycle messages: MCAP records walked and protobuf wire
format parsed in one Numba pass per decompressed chunk, straight into the record array.

The parser reads the protobuf wire format by field number (tag varint, then a varint,
fixed64, fixed32 or length-delimited value), as any protobuf decoder does: fields may
come in any order, a missing field is zero (proto3 default), an unknown field number
is skipped, a repeated scalar keeps its last value. Which field number is which record
field, with which protobuf type, comes from the file's own schema layout
(:class:`capstan.controller.log.schema.ProtoLayout`, checked by the reader against the
schema bytes stored in the file). The SI fields a live log does not store are rebuilt
afterwards from their wire fields with the logged derivations
(:func:`derive_fields`, the same float64 operations in the same order as
:func:`capstan.models.common.wire_units.apply_ops`).

Every record that is not a message of the decoded channel (schemas, channels, other
topics' messages) is handed back as ``(opcode, body offset, body length)`` for the
reader's ordinary path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from capstan.controller.log.record_bytes import (NO_DERIVATIONS, DeriveTable, apply_ops_jit, as_float, bits_f32,
                                                  f64_bits, get_le, put_le, varint, derive_fields)
from capstan.controller.log.schema import ProtoLayout
from capstan.models.common.errors import DataFormatError
from capstan.models.common.wire_units import Derivation

#: destination value kinds (record field types the compiled path writes)
_K_FLOAT_BITS, _K_F32_TO_F64, _K_BOOL = 0, 1, 2

#: kernel status codes
OK, NO_ROOM, BAD_RECORD, BAD_WIRE, WRONG_WIRE_TYPE = 0, 1, 2, 3, 4
_MESSAGE_OP = 0x05
_MSG_HEAD = 22          # channel u16, sequence u32, log_time u64, publish_time u64


@dataclass(frozen=True)
class FieldTable:
    """Per field number (index = number): expected wire type (-1: not a record field),
    byte offset and size in the record, value kind; built by :func:`field_table`."""

    wire_type: np.ndarray
    offset: np.ndarray
    size: np.ndarray
    kind: np.ndarray
    names: tuple[str, ...]      # index = field number ('' for unused numbers)
    #: the writer's fixed layout (schema.ProtoLayout): per field number the value's
    #: offset and size in a message; the tag bytes' positions and values; message size
    wire_offset: np.ndarray
    wire_size: np.ndarray
    tag_pos: np.ndarray
    tag_val: np.ndarray
    message_size: int


def raise_for_status(status: int, detail: int, table: FieldTable, topic: str, message: int, pos: int) -> None:
    """Raise the error :func:`decode_chunk` reported (nothing for OK / NO_ROOM).

    :raises DataFormatError: naming the topic, the message number, the chunk byte and,
        for a wrong wire type, the field.
    """
    if status in (OK, NO_ROOM):
        return
    what = (f"field {detail} ('{table.names[detail]}') has a wire type other than its schema's"
            if status == WRONG_WIRE_TYPE else "is not valid protobuf")
    raise DataFormatError(f"{topic}: message {message} (chunk byte {pos}) {what}")


def supported(record_dtype: np.dtype) -> bool:
    """True if every field of ``record_dtype`` is a little-endian scalar the compiled path
    writes (float64/32, int/uint 8-64 bit, bool); else the reader's numpy path is used."""
    for name in record_dtype.names or ():
        dt = record_dtype.fields[name][0]
        if dt.shape != () or dt.kind not in "fiub" or (dt.kind == "f" and dt.itemsize not in (4, 8)):
            return False
        if dt.byteorder == ">":
            return False
    return record_dtype.names is not None


def field_table(layout: ProtoLayout, record_dtype: np.dtype) -> FieldTable:
    """The field table decoding ``layout``'s messages into records of ``record_dtype``;
    stored fields ``record_dtype`` does not have are skipped (a subset read).

    :raises DataFormatError: if a stored field's type cannot be written to the record's type.
    """
    names = layout.dtype.names
    n = len(names) + 1
    wt = np.full(n, -1, np.int64)
    off = np.zeros(n, np.int64)
    size = np.zeros(n, np.int64)
    kind = np.zeros(n, np.int64)
    for number, name in enumerate(names, start=1):
        if name not in record_dtype.names:
            continue
        wdt = layout.wire_dtype.fields[name][0]
        rdt, roff = record_dtype.fields[name][:2]
        if rdt.kind == "b":
            wt[number], k = 0, _K_BOOL
        elif wdt.kind == "f" and wdt.itemsize == 4 and rdt.kind == "f" and rdt.itemsize == 8:
            wt[number], k = 5, _K_F32_TO_F64
        elif (wdt.kind == rdt.kind or (wdt.kind in "iu" and rdt.kind in "iu")) \
                and rdt.itemsize <= wdt.itemsize:
            wt[number], k = (1 if wdt.itemsize == 8 else 5), _K_FLOAT_BITS
        else:
            raise DataFormatError(f"stored field '{name}' ({wdt}) cannot be decoded into {rdt}")
        off[number], size[number], kind[number] = roff, rdt.itemsize, k
    woff = np.zeros(n, np.int64)
    wsize = np.zeros(n, np.int64)
    for number, name in enumerate(names, start=1):
        wdt, wo = layout.wire_dtype.fields[name][:2]
        woff[number], wsize[number] = wo, wdt.itemsize
    tag_pos = np.flatnonzero(layout._tag_mask).astype(np.int64)
    return FieldTable(wt, off, size, kind, ("", *names), woff, wsize, tag_pos,
                      layout.template[tag_pos].astype(np.uint8), layout.message_size)


@nb.njit(cache=True, nogil=True, inline="always")
def _store(dst, off, sz, k, v):
    """Write one field's wire value ``v`` into the record bytes as its stored type (a float32
    widened to float64, a bool normalised to 0/1); returns the stored bit pattern."""
    if k == _K_F32_TO_F64:
        v = f64_bits(np.float64(bits_f32(np.uint32(v))))
    elif k == _K_BOOL:
        v = np.uint64(1) if v != np.uint64(0) else np.uint64(0)
    put_le(dst, off, sz, v)
    return v


@nb.njit(cache=True, nogil=True)
def decode_chunk(buf, start, channel, out, row, wire_type, offset, size, kind, others, seen,
                 wire_offset, wire_size, tag_pos, tag_val, message_size,
                 skind, d_first, dst_off, op_start, op_code, op_value):  # pragma: no cover - compiled
    """Walk the MCAP records of a decompressed chunk from byte ``start``; decode every
    message of ``channel`` into ``out`` (records as a uint8 ``(rows, itemsize)`` array)
    from row ``row``; list every other record in ``others`` as (opcode, body, length).

    Derived fields are rebuilt as their source field is stored: derivations
    ``d_first[fn] .. d_first[fn + 1] - 1`` have field ``fn`` as source (record value
    kind ``skind[fn]``), each writing float64 at ``dst_off[j]`` through operations
    ``op_start[j] .. op_start[j + 1] - 1``.

    Returns ``(status, position, rows written, others listed, detail)``: ``position``
    is where the walk stopped (the record that did not fit for NO_ROOM: resume there),
    ``detail`` the offending field number for WRONG_WIRE_TYPE.

    A message of the writer's own fixed layout (``message_size`` bytes, every tag byte
    at ``tag_pos`` equal to ``tag_val``) is read at the fixed value offsets; any other
    message is parsed tag by tag.
    """
    pos = start
    end = buf.size
    n_other = 0
    nfield = wire_type.size
    r0 = row
    while pos + 9 <= end:
        op = buf[pos]
        length = get_le(buf, pos + 1, 8)
        body = pos + 9
        if length > np.uint64(end - body):
            break                                    # incomplete record: chunk ends here
        rec_end = body + np.int64(length)
        if op != _MESSAGE_OP or length < _MSG_HEAD or (buf[body] | (np.int64(buf[body + 1]) << 8)) != channel:
            others[n_other, 0] = op
            others[n_other, 1] = body
            others[n_other, 2] = np.int64(length)
            n_other += 1
            pos = rec_end
            continue
        if row >= out.shape[0]:
            return NO_ROOM, pos, row - r0, n_other, 0
        dst = out[row]
        p = body + _MSG_HEAD
        stamp = row + 1
        fixed = np.int64(length) - _MSG_HEAD == message_size
        if fixed:
            for i in range(tag_pos.size):
                if buf[p + tag_pos[i]] != tag_val[i]:
                    fixed = False
                    break
        if fixed:
            for fn in range(1, nfield):
                if wire_type[fn] < 0:
                    continue
                v = _store(dst, offset[fn], size[fn], kind[fn], get_le(buf, p + wire_offset[fn], wire_size[fn]))
                for j in range(d_first[fn], d_first[fn + 1]):
                    x = as_float(v, skind[fn], size[fn])
                    x = apply_ops_jit(x, op_start[j], op_start[j + 1], op_code, op_value)
                    put_le(dst, dst_off[j], 8, f64_bits(x))
            row += 1
            pos = rec_end
            continue
        while p < rec_end:
            b0 = buf[p]
            if b0 < 0x80:                            # one-byte tag (field numbers < 16)
                tag = np.uint64(b0)
                p += 1
            else:
                tag, p = varint(buf, p, rec_end)
                if p < 0:
                    return BAD_WIRE, pos, row - r0, n_other, 0
            fn = np.int64(tag >> np.uint64(3))
            wt = np.int64(tag & np.uint64(7))
            if wt == 5:
                if p + 4 > rec_end:
                    return BAD_WIRE, pos, row - r0, n_other, 0
                v = get_le(buf, p, 4)
                p += 4
            elif wt == 1:
                if p + 8 > rec_end:
                    return BAD_WIRE, pos, row - r0, n_other, 0
                v = get_le(buf, p, 8)
                p += 8
            elif wt == 0:
                v, p = varint(buf, p, rec_end)
                if p < 0:
                    return BAD_WIRE, pos, row - r0, n_other, 0
            elif wt == 2:
                ln, p = varint(buf, p, rec_end)
                if p < 0 or ln > np.uint64(rec_end - p):
                    return BAD_WIRE, pos, row - r0, n_other, 0
                p += np.int64(ln)
                continue                             # no record field is length-delimited
            else:
                return BAD_WIRE, pos, row - r0, n_other, 0
            if fn <= 0 or fn >= nfield or wire_type[fn] < 0:
                continue                             # unknown field: skipped, as protobuf does
            if wire_type[fn] != wt:
                return WRONG_WIRE_TYPE, pos, row - r0, n_other, fn
            _store(dst, offset[fn], size[fn], kind[fn], v)
            seen[fn] = stamp
        for fn in range(1, nfield):
            if wire_type[fn] < 0:
                continue
            if seen[fn] != stamp:                    # absent: proto3 default zero
                put_le(dst, offset[fn], size[fn], np.uint64(0))
            for j in range(d_first[fn], d_first[fn + 1]):
                x = as_float(get_le(dst, offset[fn], size[fn]), skind[fn], size[fn])
                x = apply_ops_jit(x, op_start[j], op_start[j + 1], op_code, op_value)
                put_le(dst, dst_off[j], 8, f64_bits(x))
        row += 1
        pos = rec_end
    return OK, pos, row - r0, n_other, 0


def kernel_derive(fields: FieldTable, derive: DeriveTable) -> tuple[np.ndarray, ...]:
    """``derive`` indexed by source field number, as :func:`decode_chunk` takes it:
    (skind, d_first, dst_off, op_start, op_code, op_value).

    :raises DataFormatError: if a derivation's source is not a decoded field.
    """
    nfield = fields.wire_type.size
    by_offset = {int(fields.offset[fn]): fn for fn in range(1, nfield) if fields.wire_type[fn] >= 0}
    skind = np.zeros(nfield, np.int64)
    groups: list[list[int]] = [[] for _ in range(nfield)]
    for j in range(derive.count):
        fn = by_offset.get(int(derive.src_off[j]))
        if fn is None:
            raise DataFormatError("a derivation's wire field is not decoded from the messages")
        skind[fn] = derive.src_kind[j]
        groups[fn].append(j)
    d_first = np.zeros(nfield + 1, np.int64)
    dst_off, op_start, op_code, op_value = [], [0], [], []
    for fn in range(nfield):
        d_first[fn + 1] = d_first[fn] + len(groups[fn])
        for j in groups[fn]:
            dst_off.append(int(derive.dst_off[j]))
            a, b = int(derive.op_start[j]), int(derive.op_start[j + 1])
            op_code.extend(derive.op_code[a:b].tolist())
            op_value.extend(derive.op_value[a:b].tolist())
            op_start.append(len(op_code))
    return (skind, d_first, np.asarray(dst_off, np.int64), np.asarray(op_start, np.int64),
            np.asarray(op_code, np.int64), np.asarray(op_value, np.float64))


def decode(buf: np.ndarray, start: int, channel: int, rows: np.ndarray, row: int, table: FieldTable,
           derive: tuple[np.ndarray, ...], others: np.ndarray,
           seen: np.ndarray) -> tuple[int, int, int, int, int]:
    """:func:`decode_chunk` with its tables (``derive`` from :func:`kernel_derive`)."""
    return decode_chunk(buf, start, channel, rows, row, table.wire_type, table.offset, table.size, table.kind,
                        others, seen, table.wire_offset, table.wire_size, table.tag_pos, table.tag_val,
                        table.message_size, *derive)


def warmup() -> None:
    """Load (or compile, on a cold cache) the compiled kernels with the argument types the
    reader passes, so that the first log read does not pay for it."""
    z = np.zeros(2, np.int64)
    table = FieldTable(np.full(2, -1, np.int64), z, z, z, ("", ""), z, z, z, np.zeros(2, np.uint8), -1)
    rows = np.zeros((1, 8), np.uint8)
    decode(np.frombuffer(b"", np.uint8), 0, 0, rows, 0, table, kernel_derive(table, NO_DERIVATIONS),
           np.empty((1, 3), np.int64), np.zeros(2, np.int64))
    derive_fields(np.zeros(1, [("a", "<i8"), ("b", "<f8")]), [Derivation("b", "a", (("mul", 1.0),))], ["b"])


