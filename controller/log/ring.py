"""Preallocated shared-memory ring of fixed-size records (one producer, one consumer).

The control loop pushes one record per cycle; a writer in another process drains the
ring in batches. The ring lives in a file under ``/dev/shm`` (a tmpfs, so it is plain
shared memory) mapped by both processes; the consumer attaches by the file name alone,
because the header carries the record dtype and free-form metadata.

Layout (little-endian, byte offsets)::

    0    magic b"CAPRING1"
    8    u64 header size = offset of slot 0 (multiple of 64)
    16   u64 capacity [slots]
    24   u64 itemsize [bytes per slot]
    32   u64 length of the JSON blob at offset 256
    40   u64 producer pid
    64   u64 write count   (producer only; own cache line)
    128  u64 read count    (consumer only; own cache line)
    136  u64 consumer ready flag (consumer only)
    144  u64 records durably written by the consumer (handed to the OS; consumer only)
    152  i64 ``cycle`` field of the last durably written record, -1 if none (consumer only)
    192  u64 dropped count (producer only)
    200  u64 closed flag   (producer only)
    256  JSON {"dtype": numpy descr, "meta": {...}}
    hdr  capacity slots of itemsize bytes

Counters only grow (slot = count % capacity); each has a single writer. The producer
copies the record into its slot *before* publishing the new write count, the consumer
copies slots out *before* publishing the new read count. On x86-64 (total store order,
aligned 8-byte stores are atomic) and with each step being a separate numpy call this
is enough for a single producer and a single consumer.

``push`` never blocks and never allocates an array: when the ring is full it counts
the record as dropped and returns False.
"""

from __future__ import annotations

import json
import mmap
import os
import tempfile
import uuid
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from numpy.lib.format import descr_to_dtype, dtype_to_descr

from capstan.models.common.errors import DataFormatError

MAGIC = b"CAPRING1"
_META_OFFSET = 256
# indices into the uint64 header view
_I_HDR_SIZE, _I_CAP, _I_ITEM, _I_META_LEN, _I_PID = 1, 2, 3, 4, 5
_I_WRITE, _I_READ, _I_READY, _I_DROPPED, _I_CLOSED = 8, 16, 17, 24, 25
_I_DURABLE, _I_DURABLE_CYCLE = 18, 19


class RingError(DataFormatError):
    """A ring file is missing, not a capstan ring, or inconsistent."""


def shm_dir() -> Path:
    """Directory for ring files: ``/dev/shm`` if present, else the temp directory."""
    p = Path("/dev/shm")
    return p if p.is_dir() and os.access(p, os.W_OK) else Path(tempfile.gettempdir())


def pid_alive(pid: int) -> bool:
    """True if process ``pid`` exists and is not a zombie (a killed producer's pid stays a
    zombie until its parent reaps it)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return True


def remove_stale_rings(directory: str | Path | None = None) -> list[Path]:
    """Remove ring files whose producer process is gone (a daemon killed with its writer
    leaves them behind, about 2 MB each). A file counts as stale only if its name is
    ``capstan-ring-<pid>-<id>``, it starts with the ring magic, and no process ``pid``
    exists; anything else is left alone.

    :returns: the files removed.
    """
    d = Path(directory or shm_dir())
    removed: list[Path] = []
    for f in d.glob("capstan-ring-*-*"):
        try:
            pid = int(f.name.split("-")[2])
        except (IndexError, ValueError):
            continue
        if pid <= 0 or pid_alive(pid):
            continue
        try:
            with open(f, "rb") as fh:
                if fh.read(len(MAGIC)) != MAGIC:
                    continue
            f.unlink()
            removed.append(f)
        except OSError:
            continue
    return removed


def dtype_to_json(dtype: np.dtype) -> Any:
    """JSON-serialisable description of a numpy dtype (``numpy.lib.format`` descr)."""
    return dtype_to_descr(np.dtype(dtype))


def dtype_from_json(descr: Any) -> np.dtype:
    """Inverse of :func:`dtype_to_json`.

    :raises RingError: if ``descr`` is not a valid dtype description.
    """
    try:
        if isinstance(descr, list):
            descr = [tuple(x) for x in descr]
        return descr_to_dtype(descr)
    except (TypeError, ValueError) as exc:
        raise RingError(f"invalid dtype description {descr!r}: {exc}") from exc


class LogRing:
    """A shared-memory SPSC ring of records of one structured dtype.

    Create with :meth:`create` (producer side) or :meth:`attach` (consumer side).

    :ivar path: the ring file (pass ``str(path)`` or ``name`` to the consumer).
    :ivar dtype: record dtype.
    :ivar capacity: number of slots.
    :ivar meta: the metadata mapping given at creation.
    """

    def __init__(self, path: Path, mm: mmap.mmap, owner: bool) -> None:
        self.path = path
        self._mm = mm
        self._owner = owner
        hdr = np.ndarray((32,), dtype="<u8", buffer=mm, offset=0)
        if bytes(mm[0:8]) != MAGIC:
            raise RingError(f"{path}: not a capstan ring (bad magic)")
        hdr_size, cap, item = int(hdr[_I_HDR_SIZE]), int(hdr[_I_CAP]), int(hdr[_I_ITEM])
        meta_len = int(hdr[_I_META_LEN])
        try:
            blob = json.loads(bytes(mm[_META_OFFSET:_META_OFFSET + meta_len]).decode())
        except (ValueError, UnicodeDecodeError) as exc:
            raise RingError(f"{path}: unreadable ring header: {exc}") from exc
        self.dtype = dtype_from_json(blob["dtype"])
        if self.dtype.itemsize != item or len(mm) < hdr_size + cap * item:
            raise RingError(f"{path}: header inconsistent with file size / dtype")
        self.capacity = cap
        self.meta: dict[str, Any] = dict(blob.get("meta", {}))
        self._hdr = hdr
        self._slots = np.ndarray((cap,), dtype=self.dtype, buffer=mm, offset=hdr_size)
        self._slots_u8 = np.ndarray((cap, item), dtype=np.uint8, buffer=mm, offset=hdr_size)
        # producer-side copies of its own counters (it is their only writer)
        self._w = int(hdr[_I_WRITE])
        self._dropped_local = int(hdr[_I_DROPPED])
        self._cached_rec: np.ndarray | None = None
        self._cached_u8: np.ndarray | None = None

    # ------------------------------------------------------------------ creation
    @classmethod
    def create(cls, dtype: np.dtype, capacity: int, meta: Mapping[str, Any] | None = None,
               directory: str | Path | None = None) -> "LogRing":
        """Create a new ring file (producer side); the calling process is the producer.

        :param dtype: structured record dtype.
        :param capacity: number of slots (>= 2).
        :param meta: JSON-serialisable metadata the consumer can read (topic, config, ...).
        :param directory: where to put the file (default :func:`shm_dir`).
        :raises ValueError: if capacity < 2 or the dtype has no fields.
        """
        dtype = np.dtype(dtype)
        if capacity < 2:
            raise ValueError(f"capacity must be >= 2, got {capacity}")
        if dtype.names is None:
            raise ValueError("record dtype must be a structured dtype")
        blob = json.dumps({"dtype": dtype_to_json(dtype), "meta": dict(meta or {})}).encode()
        hdr_size = (_META_OFFSET + len(blob) + 63) // 64 * 64
        size = hdr_size + capacity * dtype.itemsize
        path = Path(directory or shm_dir()) / f"capstan-ring-{os.getpid()}-{uuid.uuid4().hex[:12]}"
        fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_RDWR, 0o600)
        try:
            os.ftruncate(fd, size)
            mm = mmap.mmap(fd, size)
        finally:
            os.close(fd)
        mm[0:8] = MAGIC
        hdr = np.ndarray((32,), dtype="<u8", buffer=mm, offset=0)
        hdr[_I_HDR_SIZE], hdr[_I_CAP], hdr[_I_ITEM] = hdr_size, capacity, dtype.itemsize
        hdr[_I_META_LEN], hdr[_I_PID] = len(blob), os.getpid()
        mm[_META_OFFSET:_META_OFFSET + len(blob)] = blob
        del hdr
        return cls(path, mm, owner=True)

    @classmethod
    def attach(cls, path: str | Path) -> "LogRing":
        """Map an existing ring (consumer side).

        :raises RingError: if the file is missing or not a valid ring.
        """
        p = Path(path)
        if not p.is_absolute() and not p.exists():
            p = shm_dir() / p
        try:
            fd = os.open(p, os.O_RDWR)
        except OSError as exc:
            raise RingError(f"{p}: cannot open ring: {exc.strerror or exc}") from exc
        try:
            size = os.fstat(fd).st_size
            if size < _META_OFFSET:
                raise RingError(f"{p}: too small to be a ring ({size} bytes)")
            mm = mmap.mmap(fd, size)
        finally:
            os.close(fd)
        return cls(p, mm, owner=False)

    # ------------------------------------------------------------------ producer
    def push(self, record: np.ndarray | np.void) -> bool:
        """Append one record (shape ``(1,)`` array or ``np.void`` of :attr:`dtype`).

        O(1), never blocks. Returns False (and counts a drop) if the ring is full. When
        the caller pushes the same record buffer every cycle (``ctl.record``), its byte
        view is cached and the copy is one row assignment.
        """
        if record is self._cached_rec:
            return self.push_bytes(self._cached_u8)
        if isinstance(record, np.ndarray) and record.flags.c_contiguous and record.dtype == self.dtype:
            self._cached_rec, self._cached_u8 = record, record.view(np.uint8)
            return self.push_bytes(self._cached_u8)
        w = self._w                       # np.void or another layout: field-wise copy
        if w - int(self._hdr[_I_READ]) >= self.capacity:
            self._dropped_local += 1
            self._hdr[_I_DROPPED] = self._dropped_local
            return False
        self._slots[w % self.capacity] = record
        self._w = w + 1
        self._hdr[_I_WRITE] = self._w
        return True

    def push_bytes(self, record_u8: np.ndarray) -> bool:
        """Like :meth:`push` for a uint8 view of one record (``itemsize`` bytes)."""
        w = self._w
        if w - int(self._hdr[_I_READ]) >= self.capacity:
            self._dropped_local += 1
            self._hdr[_I_DROPPED] = self._dropped_local
            return False
        self._slots_u8[w % self.capacity] = record_u8
        self._w = w + 1
        self._hdr[_I_WRITE] = self._w    # publish after the slot is written
        return True

    def close_producer(self) -> None:
        """Mark the stream finished; the consumer drains what is left and stops."""
        self._hdr[_I_CLOSED] = 1

    # ------------------------------------------------------------------ consumer
    def set_consumer_ready(self) -> None:
        """Consumer: announce that it is draining (the producer may wait for this)."""
        self._hdr[_I_READY] = 1

    def set_durable(self, records: int, last_cycle: int) -> None:
        """Consumer: ``records`` read so far are on disk (in the OS), the last of them
        with cycle number ``last_cycle`` (-1: none)."""
        self._hdr[_I_DURABLE] = records
        self._hdr[_I_DURABLE_CYCLE] = np.int64(last_cycle).view(np.uint64)

    @property
    def durable(self) -> tuple[int, int]:
        """(records durably written by the consumer, cycle number of the last of them or -1)."""
        if int(self._hdr[_I_DURABLE]) == 0:
            return 0, -1
        return int(self._hdr[_I_DURABLE]), int(self._hdr[_I_DURABLE_CYCLE : _I_DURABLE_CYCLE + 1].view(np.int64)[0])

    @property
    def read_count(self) -> int:
        """Records the consumer has taken out of the ring so far."""
        return int(self._hdr[_I_READ])

    def reset_consumer(self) -> None:
        """Producer, after its consumer died: clear the ready flag and the durable count
        for the next consumer (which continues at the read count)."""
        self._hdr[_I_READY] = 0
        self._hdr[_I_DURABLE] = 0

    @property
    def consumer_ready(self) -> bool:
        """True once the consumer called :meth:`set_consumer_ready`."""
        return bool(self._hdr[_I_READY])

    def available(self) -> int:
        """Records waiting to be read."""
        return int(self._hdr[_I_WRITE] - self._hdr[_I_READ])

    def read_batch(self, max_n: int | None = None) -> np.ndarray:
        """Copy out up to ``max_n`` waiting records (all if None) and release their slots.

        :returns: a new array of :attr:`dtype`, possibly empty.
        """
        hdr = self._hdr
        r = int(hdr[_I_READ])
        n = int(hdr[_I_WRITE]) - r
        if max_n is not None:
            n = min(n, max_n)
        out = np.empty(n, dtype=self.dtype)
        if n:
            start = r % self.capacity
            first = min(n, self.capacity - start)
            out[:first] = self._slots[start:start + first]
            if n > first:
                out[first:] = self._slots[:n - first]
        hdr[_I_READ] = r + n           # release after copying out
        return out

    @property
    def written(self) -> int:
        """Records pushed so far (excluding drops)."""
        return int(self._hdr[_I_WRITE])

    @property
    def dropped(self) -> int:
        """Records dropped because the ring was full."""
        return int(self._hdr[_I_DROPPED])

    @property
    def closed(self) -> bool:
        """True once the producer called :meth:`close_producer`."""
        return bool(self._hdr[_I_CLOSED])

    @property
    def producer_pid(self) -> int:
        """Pid of the process that created the ring."""
        return int(self._hdr[_I_PID])

    @property
    def name(self) -> str:
        """The ring file path as a string (what the consumer attaches to)."""
        return str(self.path)

    # ------------------------------------------------------------------ teardown
    def close(self, unlink: bool | None = None) -> None:
        """Unmap the ring; remove the file if ``unlink`` (default: if we created it)."""
        if unlink is None:
            unlink = self._owner
        if unlink:
            try:
                self.path.unlink()
            except FileNotFoundError:
                pass
        self._hdr = self._slots = self._slots_u8 = None  # type: ignore[assignment]
        self._cached_rec = self._cached_u8 = None
        try:
            self._mm.close()
        except BufferError:
            pass  # a caller still holds a view; the mapping goes with the last reference
