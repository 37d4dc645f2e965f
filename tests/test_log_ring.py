"""The shared-memory record ring: FIFO order, wrap-around, drop counting, cross-process."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest

from capstan.controller.log.ring import LogRing, RingError

DT = np.dtype([("t_s", "<f8"), ("k", "<i8"), ("x", "<f4"), ("flag", "?"), ("bits", "<u2")])


def _rec(k: int) -> np.ndarray:
    r = np.zeros(1, DT)
    r["t_s"], r["k"], r["x"], r["flag"], r["bits"] = k * 1e-3, k, k * 0.5, k % 2 == 0, k % 65536
    return r


@pytest.fixture
def ring():
    r = LogRing.create(DT, 8, meta={"topic": "/t", "config_yaml": "a: 1\n"})
    yield r
    r.close()


def test_fifo_and_wraparound(ring: LogRing) -> None:
    out = []
    k = 0
    for batch in (3, 5, 7, 2, 8):          # 25 records through 8 slots: wraps several times
        for _ in range(batch):
            assert ring.push(_rec(k))
            k += 1
        got = ring.read_batch()
        assert len(got) == batch
        out.append(got)
    allr = np.concatenate(out)
    np.testing.assert_array_equal(allr["k"], np.arange(25))
    np.testing.assert_array_equal(allr["t_s"], np.arange(25) * 1e-3)
    np.testing.assert_array_equal(allr["flag"], np.arange(25) % 2 == 0)
    assert ring.dropped == 0 and ring.available() == 0


def test_full_ring_drops_and_counts(ring: LogRing) -> None:
    for k in range(8):
        assert ring.push(_rec(k))
    assert not ring.push(_rec(8))
    assert not ring.push_bytes(_rec(9).view(np.uint8))
    assert ring.dropped == 2
    got = ring.read_batch(max_n=3)
    np.testing.assert_array_equal(got["k"], [0, 1, 2])
    assert ring.push(_rec(10))             # room again after the consumer released slots
    np.testing.assert_array_equal(ring.read_batch()["k"], [3, 4, 5, 6, 7, 10])


def test_push_bytes_equals_push(ring: LogRing) -> None:
    r = _rec(42)
    ring.push_bytes(r.view(np.uint8))
    ring.push(r[0])
    got = ring.read_batch()
    assert got[0] == r[0] and got[1] == r[0]


def test_attach_reads_dtype_and_meta(ring: LogRing) -> None:
    ring.push(_rec(1))
    ring.close_producer()
    other = LogRing.attach(ring.name)
    try:
        assert other.dtype == DT and other.capacity == 8
        assert other.meta == {"topic": "/t", "config_yaml": "a: 1\n"}
        assert other.closed and other.available() == 1
        assert other.read_batch()["k"][0] == 1
        assert ring.available() == 0      # the read count is shared
    finally:
        other.close()


def test_attach_rejects_non_ring(tmp_path) -> None:
    bad = tmp_path / "x"
    bad.write_bytes(b"\0" * 1024)
    with pytest.raises(RingError, match="bad magic"):
        LogRing.attach(bad)
    with pytest.raises(RingError, match="cannot open"):
        LogRing.attach(tmp_path / "missing")


def test_create_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError, match="capacity"):
        LogRing.create(DT, 1)
    with pytest.raises(ValueError, match="structured"):
        LogRing.create(np.float64, 4)


def test_cross_process_producer_no_loss_no_tearing() -> None:
    """A producer in another process pushes 200k records through a 1024-slot ring
    while we drain; every record arrives once, in order, with consistent fields."""
    ring = LogRing.create(DT, 1024)
    n = 200_000
    code = textwrap.dedent(f"""
        import numpy as np
        from capstan.controller.log.ring import LogRing
        ring = LogRing.attach({ring.name!r})
        r = np.zeros(1, ring.dtype)
        k = 0
        while k < {n}:
            r["t_s"] = k * 1e-3; r["k"] = k; r["x"] = k * 0.5; r["flag"] = k % 2 == 0; r["bits"] = k % 65536
            if ring.push(r):
                k += 1
        ring.close_producer()
    """)
    proc = subprocess.Popen([sys.executable, "-c", code])
    try:
        got = []
        while True:
            closed = ring.closed
            b = ring.read_batch()
            if len(b):
                got.append(b)
            elif closed:
                break
        allr = np.concatenate(got)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        ring.close()
    k = np.arange(n)
    np.testing.assert_array_equal(allr["k"], k)
    np.testing.assert_array_equal(allr["t_s"], k * 1e-3)
    np.testing.assert_array_equal(allr["x"], (k * 0.5).astype(np.float32))
    np.testing.assert_array_equal(allr["bits"], k % 65536)
