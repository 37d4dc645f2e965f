"""Columnar blocks of cycle records: the codec of the archive form of a log.

A block holds ``n`` consecutive records as one protobuf message (``capstan.ArchiveBlock``:
``uint32 n = 1`` then one ``bytes`` field per column, in column order), so a generic
protobuf decoder reads it with the schema stored in the file. Each column is one
field's values of the block, transformed so that zstd finds the structure a row layout
hides, and exactly reversible:

* ``delta``: integers as the difference to the previous value (the first absolute),
  int64 wrap-around arithmetic (``t_ns``, ``cycle``);
* ``age_delta``: a device receive time as ``t_ns - time`` (its age at the cycle), then
  ``delta``;
* ``raw``: the values as they are;

and then byte-shuffled (all first bytes of the values, then all second bytes, ...),
which groups the slowly varying sign/exponent bytes of floats and the high bytes of
integers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capstan.controller.log.schema import LogFormatError, _int_field, _len_field

BLOCK_MESSAGE = "capstan.ArchiveBlock"
_TYPE_UINT32, _TYPE_BYTES, _LABEL_OPTIONAL = 13, 12, 1
TRANSFORMS = ("raw", "delta", "age_delta")


@dataclass(frozen=True)
class Column:
    """One archived field: name, numpy dtype (as stored), transform."""

    name: str
    dtype: np.dtype
    transform: str = "raw"

    def to_json(self) -> dict[str, str]:
        """JSON form (numpy dtype string)."""
        return {"name": self.name, "dtype": np.dtype(self.dtype).str, "transform": self.transform}

    @classmethod
    def from_json(cls, obj: dict[str, str]) -> "Column":
        """Inverse of :meth:`to_json`.

        :raises LogFormatError: on a malformed entry or an unknown transform.
        """
        try:
            col = cls(str(obj["name"]), np.dtype(obj["dtype"]), str(obj.get("transform", "raw")))
        except (KeyError, TypeError) as exc:
            raise LogFormatError(f"malformed archive column {obj!r}: {exc}") from exc
        if col.transform not in TRANSFORMS:
            raise LogFormatError(f"archive column {col.name}: unknown transform {col.transform!r}")
        return col


def _delta(x: np.ndarray) -> np.ndarray:
    v = x.astype(np.int64)
    out = np.empty_like(v)
    if len(v):
        out[0] = v[0]
        out[1:] = v[1:] - v[:-1]
    return out


def _shuffle(a: np.ndarray) -> bytes:
    a = np.ascontiguousarray(a)
    return a.view(np.uint8).reshape(len(a), a.dtype.itemsize).T.tobytes()


def _unshuffle(b: bytes, dtype: np.dtype, n: int) -> np.ndarray:
    raw = np.frombuffer(b, np.uint8)
    if raw.size != n * dtype.itemsize:
        raise LogFormatError(f"archive column: {raw.size} bytes for {n} values of {dtype}")
    return np.ascontiguousarray(raw.reshape(dtype.itemsize, n).T).reshape(-1).view(dtype)


def encode_column(col: Column, values: np.ndarray, t_ns: np.ndarray | None) -> bytes:
    """Transformed, byte-shuffled bytes of one column of a block."""
    if col.transform == "raw":
        return _shuffle(np.asarray(values).astype(col.dtype))
    v = values.astype(np.int64)
    if col.transform == "age_delta":
        assert t_ns is not None
        v = t_ns.astype(np.int64) - v
    return _shuffle(_delta(v))


def decode_column(col: Column, data: bytes, n: int, t_ns: np.ndarray | None) -> np.ndarray:
    """Inverse of :func:`encode_column`.

    :raises LogFormatError: if the byte count does not fit ``n`` values.
    """
    if col.transform == "raw":
        return _unshuffle(data, np.dtype(col.dtype), n)
    v = np.cumsum(_unshuffle(data, np.dtype("<i8"), n), dtype=np.int64)
    if col.transform == "age_delta":
        assert t_ns is not None
        v = t_ns.astype(np.int64) - v
    return v.astype(col.dtype)


def encode_block(columns: list[Column], records: np.ndarray, time_column: str) -> bytes:
    """One block message for ``records`` (``time_column`` must precede ``age_delta`` columns)."""
    out = bytearray(_int_field(1, len(records)))
    t = records[time_column] if time_column else None
    for k, col in enumerate(columns, start=2):
        out += _len_field(k, encode_column(col, records[col.name], t))
    return bytes(out)


def decode_block(columns: list[Column], data: bytes, time_column: str) -> dict[str, np.ndarray]:
    """Columns of one block message.

    :raises LogFormatError: if the message does not have the block layout.
    """
    fields: dict[int, bytes] = {}
    pos, n = 0, -1
    mv = memoryview(data)
    while pos < len(data):
        key, pos = _read_varint(data, pos)
        number, wt = key >> 3, key & 7
        if wt == 0:
            value, pos = _read_varint(data, pos)
            if number == 1:
                n = value
        elif wt == 2:
            length, pos = _read_varint(data, pos)
            fields[number] = bytes(mv[pos:pos + length])
            pos += length
        else:
            raise LogFormatError(f"archive block: unexpected wire type {wt} of field {number}")
    if n < 0:
        raise LogFormatError("archive block without its record count")
    out: dict[str, np.ndarray] = {}
    for k, col in enumerate(columns, start=2):
        if k not in fields:
            raise LogFormatError(f"archive block lacks column {col.name}")
        out[col.name] = decode_column(col, fields[k], n, out.get(time_column))
    return out


def _read_varint(data: bytes, pos: int) -> tuple[int, int]:
    shift = value = 0
    while True:
        if pos >= len(data):
            raise LogFormatError("archive block: truncated varint")
        b = data[pos]
        pos += 1
        value |= (b & 0x7F) << shift
        if not b & 0x80:
            return value, pos
        shift += 7


def block_schema(columns: list[Column]) -> bytes:
    """Serialized FileDescriptorSet of :data:`BLOCK_MESSAGE` for ``columns``."""
    package, _, short = BLOCK_MESSAGE.rpartition(".")

    def field(name: str, number: int, ptype: int) -> bytes:
        return _len_field(2, _len_field(1, name.encode()) + _int_field(3, number) + _int_field(4, _LABEL_OPTIONAL)
                          + _int_field(5, ptype) + _len_field(10, name.encode()))

    body = _len_field(1, short.encode()) + field("n", 1, _TYPE_UINT32)
    for k, col in enumerate(columns, start=2):
        body += field(col.name, k, _TYPE_BYTES)
    file_proto = (_len_field(1, f"{BLOCK_MESSAGE.replace('.', '/')}.proto".encode()) + _len_field(2, package.encode())
                  + _len_field(4, body) + _len_field(12, b"proto3"))
    return _len_field(1, file_proto)

