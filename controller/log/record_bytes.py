"""Compiled byte-level work on structured records (Numba, cached): little-endian loads
and stores at byte offsets, register bit casts, the SI fields rebuilt from their wire
fields (the float64 operations of :func:`capstan.models.common.wire_units.apply_ops`,
in the same order), and field copies between record arrays in one row-major pass.

Used by :mod:`capstan.controller.log.wire_decode` (decoding chunks) and by the reader
and replay on whole arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numba as nb
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from capstan.models.common.errors import DataFormatError
from capstan.models.common.wire_units import Derivation

#: source kinds of a derivation (record field type -> float64)
_S_SIGNED, _S_UNSIGNED, _S_F32, _S_F64 = 0, 1, 2, 3
#: derivation op codes, in the order of wire_units.OPS
_OPS = {"mul": 0, "add": 1, "sub": 2, "div": 3}


@intrinsic
def bits_f64(typingctx, v):                        # pragma: no cover - compiled
    """uint64 bits -> float64 (a register reinterpretation)."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())
    return types.float64(types.uint64), codegen


@intrinsic
def f64_bits(typingctx, x):                        # pragma: no cover - compiled
    """float64 -> its uint64 bits."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(64))
    return types.uint64(types.float64), codegen


@intrinsic
def bits_f32(typingctx, v):                        # pragma: no cover - compiled
    """uint32 bits -> float32."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.FloatType())
    return types.float32(types.uint32), codegen


@nb.njit(cache=True, nogil=True, inline="always")
def varint(buf, p, end):                           # pragma: no cover - compiled
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
def get_le(rec, o, k):                                # pragma: no cover - compiled
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
def put_le(dst, o, k, v):                             # pragma: no cover - compiled
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
def as_float(v, skind, s):                         # pragma: no cover - compiled
    """A record field's value (its ``s`` bytes in ``v``) as float64, as numpy's
    ``astype(float64)`` makes it."""
    if skind == _S_F64:
        return bits_f64(v)
    if skind == _S_F32:
        return np.float64(bits_f32(np.uint32(v & np.uint64(0xFFFFFFFF))))
    if s < 8:
        v &= (np.uint64(1) << np.uint64(8 * s)) - np.uint64(1)
    if skind == _S_UNSIGNED:
        return np.float64(v)
    sh = np.uint64(64 - 8 * s)                      # signed: sign-extend from s bytes
    return np.float64(np.int64(v << sh) >> np.int64(sh))


@nb.njit(cache=True, nogil=True, inline="always")
def apply_ops_jit(x, a, b, op_code, op_value):             # pragma: no cover - compiled
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
def _derive(out, src_off, src_size, src_kind, dst_off, op_start, op_code,
            op_value):                              # pragma: no cover - compiled
    for r in range(out.shape[0]):
        rec = out[r]
        for j in range(src_off.size):
            x = as_float(get_le(rec, src_off[j], src_size[j]), src_kind[j], src_size[j])
            x = apply_ops_jit(x, op_start[j], op_start[j + 1], op_code, op_value)
            put_le(rec, dst_off[j], 8, f64_bits(x))


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
