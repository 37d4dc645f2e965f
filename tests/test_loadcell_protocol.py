"""Load-cell amplifier frame: exact bytes, parser accounting, fuzzing with 1e5 frames."""

from __future__ import annotations

import math
import random
import struct

from capstan.drivers.serial.loadcell_protocol import FRAME_LEN, LoadCellParser, build_frame, parse_frame


def test_frame_bytes_exact() -> None:
    raw = build_frame((1.0, -1.0, 0.5, 2.0))
    # 3F+80+BF+80+3F+40 = 0x27D -> checksum 0x7D
    assert raw == bytes.fromhex("AA 3F800000 BF800000 3F000000 40000000 7D 55")
    assert len(raw) == FRAME_LEN
    assert parse_frame(raw) == (1.0, -1.0, 0.5, 2.0)


def test_parse_frame_rejects() -> None:
    good = build_frame((0.1, 0.2, 0.3, 0.4))
    assert parse_frame(good[:-1]) is None
    assert parse_frame(good + b"\x00") is None and parse_frame(good + good) is None  # exactly one frame
    assert parse_frame(good[:-1] + b"\x54") is None  # end byte
    assert parse_frame(b"\xab" + good[1:]) is None  # start byte
    assert parse_frame(good[:17] + bytes(((good[17] + 1) & 0xFF,)) + good[18:]) is None
    nan = build_frame((math.nan, 0.0, 0.0, 0.0))
    assert parse_frame(nan) is None


def test_partial_first_frame_not_counted_and_byte_by_byte() -> None:
    frames = [build_frame((i, -i, 2 * i, 0.5)) for i in range(5)]
    blob = frames[0][7:] + b"".join(frames[1:])
    p = LoadCellParser()
    out = []
    for b in blob:
        out += p.feed(bytes((b,)))
    assert out == [(float(i), float(-i), float(2 * i), 0.5) for i in range(1, 5)]
    assert p.stats.good_frames == 4 and p.stats.bad_frames == 0


def test_garbage_between_frames_counts_one_bad_and_one_resync() -> None:
    a, b = build_frame((1, 2, 3, 4)), build_frame((5, 6, 7, 8))
    p = LoadCellParser()
    out = p.feed(a + b"\xaa\x00\x55garbage" + b)
    assert out == [(1, 2, 3, 4), (5, 6, 7, 8)]
    assert (p.stats.good_frames, p.stats.bad_frames, p.stats.resyncs) == (2, 1, 1)


def _fuzz_blob(seed: int, n: int) -> tuple[bytes, list[tuple[float, ...]], int]:
    """n frames; damage (checksum, truncation, random garbage) only after an intact
    frame, so each damage event is detectable at the position of an expected frame."""
    rng = random.Random(seed)
    parts, valid, events = [], [], 0
    prev_ok = True
    for _ in range(n):
        vals = struct.unpack(">4f", struct.pack(">4f", *(rng.uniform(-3, 3) for _ in range(4))))
        f = build_frame(vals)
        r = rng.random() if prev_ok else 1.0
        if r < 0.05:
            parts.append(f[:17] + bytes(((f[17] + rng.randint(1, 255)) & 0xFF,)) + f[18:])
        elif r < 0.10:
            parts.append(f[:rng.randint(1, FRAME_LEN - 1)])
        elif r < 0.15:
            parts.append(rng.randbytes(rng.randint(1, 50)) + f)
            valid.append(vals)
        else:
            parts.append(f)
            valid.append(vals)
            prev_ok = True
            continue
        events += 1
        prev_ok = False
    return b"".join(parts), valid, events


def test_fuzz_1e5_frames_exact_recovery() -> None:
    blob, valid, events = _fuzz_blob(11, 100_000)
    rng = random.Random(5)
    p = LoadCellParser()
    out = []
    i = 0
    while i < len(blob):
        k = rng.randint(1, 3000)
        out += p.feed(blob[i:i + k])
        i += k
    assert out == valid
    assert p.stats.good_frames == len(valid)
    # every damage event (checksum, truncation, garbage) costs one bad frame at the
    # expected frame position; while hunting over <= ~70 bytes, a byte pair 0xAA ... 0x55
    # 18 bytes apart (probability 2**-16 per position) adds a bad candidate
    assert p.stats.bad_frames >= events
    assert p.stats.bad_frames - events <= 3 * events * 70 / 65536 + 5
    assert p.stats.resyncs == events
    assert p.buffered < FRAME_LEN


def test_fuzz_pure_random_bytes_no_exception() -> None:
    rng = random.Random(9)
    p = LoadCellParser()
    for _ in range(200):
        p.feed(rng.randbytes(10_000))
    # false frames need start, end and checksum to match: ~2**-24 per position
    assert p.stats.good_frames <= 2
