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
from typing import Sequence

import numba as nb
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from capstan.controller.log.schema import ProtoLayout
from capstan.models.common.errors import DataFormatError
from capstan.models.common.wire_units import Derivation

#: destination value kinds (record field types the compiled path writes)
_K_FLOAT_BITS, _K_F32_TO_F64, _K_BOOL = 0, 1, 2
#: source kinds of a derivation (record field type -> float64)
_S_SIGNED, _S_UNSIGNED, _S_F32, _S_F64 = 0, 1, 2, 3
#: derivation op codes, in the order of wire_units.OPS
_OPS = {"mul": 0, "add": 1, "sub": 2, "div": 3}

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


@intrinsic
def _bits_f64(typingctx, v):                        # pragma: no cover - compiled
    """uint64 bits -> float64 (a register reinterpretation)."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())
    return types.float64(types.uint64), codegen


@intrinsic
def _f64_bits(typingctx, x):                        # pragma: no cover - compiled
    """float64 -> its uint64 bits."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(64))
    return types.uint64(types.float64), codegen


@intrinsic
def _bits_f32(typingctx, v):                        # pragma: no cover - compiled
    """uint32 bits -> float32."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.FloatType())
    return types.float32(types.uint32), codegen


@nb.njit(cache=True, nogil=True, inline="always")
def _varint(buf, p, end):                           # pragma: no cover - compiled
    """(value, next position); next position -1 if the varint runs past ``end``."""
    v = np.uint64(0)
    shift = 0
    while p < end and shift < 64:
        b = buf[p]
        p += 1
        v |= np.uint64(b & 0x7F) << np.uint64(shift)
        if b < 0x80:
            return v, p
        shift += 7
    return v, -1


@nb.njit(cache=True, nogil=True, inline="always")
def _get(rec, o, k):                                # pragma: no cover - compiled
    """The ``k`` bytes at ``rec[o]`` as a little-endian uint64 (8 and 4 written out, so
    the compiler makes them one load)."""
    if k == 8:
        return (np.uint64(rec[o]) | (np.uint64(rec[o + 1]) << np.uint64(8))
                | (np.uint64(rec[o + 2]) << np.uint64(16)) | (np.uint64(rec[o + 3]) << np.uint64(24))
                | (np.uint64(rec[o + 4]) << np.uint64(32)) | (np.uint64(rec[o + 5]) << np.uint64(40))
                | (np.uint64(rec[o + 6]) << np.uint64(48)) | (np.uint64(rec[o + 7]) << np.uint64(56)))
    if k == 4:
        return (np.uint64(rec[o]) | (np.uint64(rec[o + 1]) << np.uint64(8))
                | (np.uint64(rec[o + 2]) << np.uint64(16)) | (np.uint64(rec[o + 3]) << np.uint64(24)))
    v = np.uint64(0)
    for i in range(k):
        v |= np.uint64(rec[o + i]) << np.uint64(8 * i)
    return v


@nb.njit(cache=True, nogil=True, inline="always")
def _put(dst, o, k, v):                             # pragma: no cover - compiled
    """Store the low ``k`` bytes of ``v`` little-endian at ``dst[o]``."""
    if k == 8:
        dst[o] = np.uint8(v & np.uint64(0xFF))
        dst[o + 1] = np.uint8((v >> np.uint64(8)) & np.uint64(0xFF))
        dst[o + 2] = np.uint8((v >> np.uint64(16)) & np.uint64(0xFF))
        dst[o + 3] = np.uint8((v >> np.uint64(24)) & np.uint64(0xFF))
        dst[o + 4] = np.uint8((v >> np.uint64(32)) & np.uint64(0xFF))
        dst[o + 5] = np.uint8((v >> np.uint64(40)) & np.uint64(0xFF))
        dst[o + 6] = np.uint8((v >> np.uint64(48)) & np.uint64(0xFF))
        dst[o + 7] = np.uint8((v >> np.uint64(56)) & np.uint64(0xFF))
    elif k == 4:
        dst[o] = np.uint8(v & np.uint64(0xFF))
        dst[o + 1] = np.uint8((v >> np.uint64(8)) & np.uint64(0xFF))
        dst[o + 2] = np.uint8((v >> np.uint64(16)) & np.uint64(0xFF))
        dst[o + 3] = np.uint8((v >> np.uint64(24)) & np.uint64(0xFF))
    else:
        for i in range(k):
            dst[o + i] = np.uint8((v >> np.uint64(8 * i)) & np.uint64(0xFF))


@nb.njit(cache=True, nogil=True, inline="always")
def _as_float(v, skind, s):                         # pragma: no cover - compiled
    """A record field's value (its ``s`` bytes in ``v``) as float64, as numpy's
    ``astype(float64)`` makes it."""
    if skind == _S_F64:
        return _bits_f64(v)
    if skind == _S_F32:
        return np.float64(_bits_f32(np.uint32(v & np.uint64(0xFFFFFFFF))))
    if s < 8:
        v &= (np.uint64(1) << np.uint64(8 * s)) - np.uint64(1)
    if skind == _S_UNSIGNED:
        return np.float64(v)
    sh = np.uint64(64 - 8 * s)                      # signed: sign-extend from s bytes
    return np.float64(np.int64(v << sh) >> np.int64(sh))


@nb.njit(cache=True, nogil=True, inline="always")
def _apply(x, a, b, op_code, op_value):             # pragma: no cover - compiled
    """``x`` through the operations ``a..b-1`` in order (wire_units.apply_ops)."""
    for q in range(a, b):
        c, w = op_code[q], op_value[q]
        if c == 0:
            x = x * w
        elif c == 1:
            x = x + w
        elif c == 2:
            x = x - w
        else:
            x = x / w
    return x


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
        length = _get(buf, pos + 1, 8)
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
                v = _get(buf, p + wire_offset[fn], wire_size[fn])
                k = kind[fn]
                if k == _K_F32_TO_F64:
                    v = _f64_bits(np.float64(_bits_f32(np.uint32(v))))
                elif k == _K_BOOL:
                    v = np.uint64(1) if v != np.uint64(0) else np.uint64(0)
                _put(dst, offset[fn], size[fn], v)
                for j in range(d_first[fn], d_first[fn + 1]):
                    x = _as_float(v, skind[fn], size[fn])
                    x = _apply(x, op_start[j], op_start[j + 1], op_code, op_value)
                    _put(dst, dst_off[j], 8, _f64_bits(x))
            row += 1
            pos = rec_end
            continue
        while p < rec_end:
            b0 = buf[p]
            if b0 < 0x80:                            # one-byte tag (field numbers < 16)
                tag = np.uint64(b0)
                p += 1
            else:
                tag, p = _varint(buf, p, rec_end)
                if p < 0:
                    return BAD_WIRE, pos, row - r0, n_other, 0
            fn = np.int64(tag >> np.uint64(3))
            wt = np.int64(tag & np.uint64(7))
            if wt == 5:
                if p + 4 > rec_end:
                    return BAD_WIRE, pos, row - r0, n_other, 0
                v = _get(buf, p, 4)
                p += 4
            elif wt == 1:
                if p + 8 > rec_end:
                    return BAD_WIRE, pos, row - r0, n_other, 0
                v = _get(buf, p, 8)
                p += 8
            elif wt == 0:
                v, p = _varint(buf, p, rec_end)
                if p < 0:
                    return BAD_WIRE, pos, row - r0, n_other, 0
            elif wt == 2:
                ln, p = _varint(buf, p, rec_end)
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
            k = kind[fn]
            if k == _K_F32_TO_F64:
                v = _f64_bits(np.float64(_bits_f32(np.uint32(v))))
            elif k == _K_BOOL:
                v = np.uint64(1) if v != np.uint64(0) else np.uint64(0)
            _put(dst, offset[fn], size[fn], v)
            seen[fn] = stamp
        for fn in range(1, nfield):
            if wire_type[fn] < 0:
                continue
            if seen[fn] != stamp:                    # absent: proto3 default zero
                _put(dst, offset[fn], size[fn], np.uint64(0))
            for j in range(d_first[fn], d_first[fn + 1]):
                x = _as_float(_get(dst, offset[fn], size[fn]), skind[fn], size[fn])
                x = _apply(x, op_start[j], op_start[j + 1], op_code, op_value)
                _put(dst, dst_off[j], 8, _f64_bits(x))
        row += 1
        pos = rec_end
    return OK, pos, row - r0, n_other, 0


@nb.njit(cache=True, nogil=True)
def _derive(out, src_off, src_size, src_kind, dst_off, op_start, op_code,
            op_value):                              # pragma: no cover - compiled
    for r in range(out.shape[0]):
        rec = out[r]
        for j in range(src_off.size):
            x = _as_float(_get(rec, src_off[j], src_size[j]), src_kind[j], src_size[j])
            x = _apply(x, op_start[j], op_start[j + 1], op_code, op_value)
            _put(rec, dst_off[j], 8, _f64_bits(x))


@dataclass(frozen=True)
class DeriveTable:
    """Compiled form of the derivations of some float64 record fields (see
    :func:`derive_table`); ``count`` 0 derives nothing."""

    src_off: np.ndarray
    src_size: np.ndarray
    src_kind: np.ndarray
    dst_off: np.ndarray
    op_start: np.ndarray
    op_code: np.ndarray
    op_value: np.ndarray

    @property
    def count(self) -> int:
        """Number of derived fields."""
        return int(self.src_off.size)

    def arrays(self) -> tuple[np.ndarray, ...]:
        """The arrays in the order the kernels take them."""
        return (self.src_off, self.src_size, self.src_kind, self.dst_off, self.op_start, self.op_code,
                self.op_value)


def derive_table(dtype: np.dtype, derivations: Sequence[Derivation], missing: Sequence[str]) -> DeriveTable:
    """The table computing each of ``missing`` (float64 fields of ``dtype``) from its wire
    field with the derivation's float64 operations in order.

    :raises DataFormatError: if a derivation is missing, its source is not a field of
        ``dtype``, or a target is not float64.
    """
    by_field = {d.field: d for d in derivations}
    src_off, src_size, src_kind, dst_off, op_start, op_code, op_value = [], [], [], [], [0], [], []
    for name in missing:
        d = by_field.get(name)
        if d is None or d.source not in dtype.names:
            raise DataFormatError(f"field '{name}' is neither stored nor derivable from a stored wire field")
        sdt, soff = dtype.fields[d.source][:2]
        tdt, toff = dtype.fields[name][:2]
        if tdt != np.float64:
            raise DataFormatError(f"derived field '{name}' is {tdt}, not float64")
        src_off.append(soff)
        src_size.append(sdt.itemsize)
        src_kind.append({"i": _S_SIGNED, "u": _S_UNSIGNED, "b": _S_UNSIGNED}.get(
            sdt.kind, _S_F32 if sdt.itemsize == 4 else _S_F64))
        dst_off.append(toff)
        for op, v in d.ops:
            op_code.append(_OPS[op])
            op_value.append(v)
        op_start.append(len(op_code))
    i64 = lambda x: np.asarray(x, np.int64)  # noqa: E731
    return DeriveTable(i64(src_off), i64(src_size), i64(src_kind), i64(dst_off), i64(op_start),
                       i64(op_code), np.asarray(op_value, np.float64))


NO_DERIVATIONS = derive_table(np.dtype([("x", "f8")]), (), ())


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


def derive_fields(records: np.ndarray, derivations: Sequence[Derivation], missing: Sequence[str]) -> None:
    """Compute each of ``missing`` (float64 fields of ``records``) from its wire field, in
    place, with the derivation's float64 operations in order (bit for bit as
    :func:`capstan.models.common.wire_units.apply_ops` on float64 arrays).

    :raises DataFormatError: as :func:`derive_table`.
    """
    table = derive_table(records.dtype, derivations, missing)
    if not table.count or not len(records):
        return
    rows = records.view(np.uint8).reshape(len(records), records.dtype.itemsize)
    _derive(rows, *table.arrays())


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


@nb.njit(cache=True, nogil=True)
def _copy_rows(dst, src, d_off, s_off, size):       # pragma: no cover - compiled
    for r in range(dst.shape[0]):
        for j in range(d_off.size):
            for i in range(size[j]):
                dst[r, d_off[j] + i] = src[r, s_off[j] + i]


def copy_fields(dst: np.ndarray, src: np.ndarray, names: Sequence[str]) -> None:
    """``dst[name] = src[name]`` for each of ``names``, in one row-major compiled pass
    (numpy copies a field at a time, striding both arrays once per field); fields of
    the same type in both, else numpy's assignment (which converts).

    :raises ValueError: if the arrays differ in length.
    """
    if len(dst) != len(src):
        raise ValueError(f"copy_fields: {len(dst)} rows into {len(src)}")
    same = [n for n in names if dst.dtype.fields[n][0] == src.dtype.fields[n][0]]
    for n in names:
        if n not in same:
            dst[n] = src[n]
    if not same or not len(dst) or not (dst.flags.c_contiguous and src.flags.c_contiguous):
        for n in same:
            dst[n] = src[n]
        return
    d = dst.view(np.uint8).reshape(len(dst), dst.dtype.itemsize)
    s = src.view(np.uint8).reshape(len(src), src.dtype.itemsize)
    _copy_rows(d, s, np.array([dst.dtype.fields[n][1] for n in same], np.int64),
               np.array([src.dtype.fields[n][1] for n in same], np.int64),
               np.array([dst.dtype.fields[n][0].itemsize for n in same], np.int64))
