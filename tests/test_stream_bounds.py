"""Stream parsers under adversarial bytes: bounded frame length, look-ahead, exact accounting.

Frames here are built with ``struct`` from the MT protocol layout (not with capstan's
builders), and the line is modelled as a reader that polls whatever arrived: a frame
counts as delivered late if the parser returns it in a later ``feed`` than the one
that brought its last byte.
"""

from __future__ import annotations

import random
import struct

import pytest

from capstan.drivers.interfaces import LinkStats
from capstan.drivers.serial.loadcell_protocol import FRAME_LEN, LoadCellParser
from capstan.drivers.serial.xbus import XbusParser
from capstan.drivers.serial.xsens import XsensConfig, output_configuration
from capstan.drivers.serial.xsens_protocol import mtdata2_max_len, mtdata2_well_formed, parse_mtdata2
from capstan.models.common.errors import ProtocolError

FAKE_HEADERS = [
    bytes.fromhex("FA FF 36 FF 07 FF"),  # extended length 2047 (the field report)
    bytes.fromhex("FA FF 36 FF 08 00"),  # extended length 2048, the protocol maximum
    bytes.fromhex("FA FF 36 FE"),        # standard length 254, the standard maximum
    bytes.fromhex("FA FF 42 FF 08 00"),  # an Error message of maximal length
    bytes.fromhex("FA FF 36 35"),        # standard length 53: exactly the float32 packet, at the bound
]


def _msg(mid: int, data: bytes) -> bytes:
    """Xbus message from the layout: FA FF MID LEN [EXT_HI EXT_LO] DATA CS, BID..CS sum to 0."""
    n = len(data)
    body = bytes((0xFF, mid, n) if n < 255 else (0xFF, mid, 0xFF, n >> 8, n & 0xFF)) + data
    return b"\xFA" + body + bytes(((-sum(body)) & 0xFF,))


def _packet(counter: int, q: tuple[float, float, float, float], w: tuple[float, float, float]) -> bytes:
    """MTData2 with the driver's default items: counter, SampleTimeFine, quaternion, rate, status."""
    data = (struct.pack(">HBH", 0x1020, 2, counter) + struct.pack(">HBI", 0x1060, 4, 25 * counter)
            + struct.pack(">HB4f", 0x2010, 16, *q) + struct.pack(">HB3f", 0x8020, 12, *w)
            + struct.pack(">HBI", 0xE020, 4, 3))
    return _msg(0x36, data)


def _packet_with_preambles(counter: int, rng: random.Random) -> bytes:
    """A packet whose float bytes contain FA FF and a header claiming the bound (standard length)."""
    q = struct.unpack(">f", bytes.fromhex("FA FF 36 35"))[0]
    w = struct.unpack(">f", bytes.fromhex("3F FA FF 36"))[0]
    return _packet(counter, (rng.random(), q, rng.random(), 0.5), (w, rng.random(), -w))


def _bounded() -> XbusParser:
    """A parser bounded as the driver bounds it in measurement mode (default float32 output)."""
    n = mtdata2_max_len(output_configuration(XsensConfig(port="x")))
    return XbusParser(LinkStats(), max_data_len=254, limits={0x36: n})


def _play(parser, parts: list[tuple[bytes, bool]], rng: random.Random, max_chunk: int):
    """Feed ``parts`` (bytes, genuine?) in random chunks; per genuine frame: feed index of its
    last byte. Returns (returned frames with the feed index they came out of, completion indices)."""
    blob = b"".join(p for p, _ in parts)
    ends, pos = [], 0
    for p, genuine in parts:
        pos += len(p)
        if genuine:
            ends.append((pos, p))
    got, done, i, feed_no = [], {}, 0, 0
    e = 0
    while i < len(blob):
        j = min(len(blob), i + rng.randint(1, max_chunk))
        while e < len(ends) and ends[e][0] <= j:
            done[ends[e][1]] = feed_no
            e += 1
        for item in parser.feed(blob[i:j]):
            got.append((_msg(*item) if isinstance(parser, XbusParser) else item, feed_no))
        i = j
        feed_no += 1
    return got, done


def _genuine_stream(rng: random.Random, n: int, fake_every: int, preambles: bool) -> list[tuple[bytes, bool]]:
    parts: list[tuple[bytes, bool]] = []
    for c in range(n):
        if c % fake_every == 0:
            fake = rng.choice(FAKE_HEADERS)
            parts.append((fake + rng.randbytes(rng.randint(0, 8)), False))
        pkt = _packet_with_preambles(c, rng) if preambles and c % 3 == 0 else _packet(
            c, (rng.random(), rng.random(), rng.random(), rng.random()), (rng.random(), 0.0, -1.0))
        parts.append((pkt, True))
    return parts


@pytest.mark.parametrize("bounded", [True, False], ids=["driver-bound", "protocol-max-2048"])
@pytest.mark.parametrize("preambles", [False, True], ids=["plain", "preambles-in-payload"])
def test_fake_headers_delay_no_genuine_frame(bounded: bool, preambles: bool) -> None:
    """20 000 packets, a forged maximal-length header before every 4th, read in pieces of
    1..60 bytes: every genuine packet is returned in the very feed that completes it.

    A forged header is only completed (and then accepted) if the bytes behind it happen
    to give a matching 8-bit checksum: lost packets <= 3 x forged / 256 + 3.
    """
    rng = random.Random(20 + bounded + 2 * preambles)
    parts = _genuine_stream(rng, 20_000, 4, preambles)
    parser = _bounded() if bounded else XbusParser()
    got, done = _play(parser, parts, rng, 60)
    genuine = [p for p, g in parts if g]
    out_at = {f: k for f, k in got}
    lost = [f for f in genuine if f not in out_at]
    n_fake = len(parts) - len(genuine)
    assert len(lost) <= 3 * n_fake / 256 + 3
    late = [f for f in genuine if f in out_at and out_at[f] > done[f]]
    assert late == []
    # genuine frames come out in stream order
    order = [genuine.index(f) for f, _ in got if f in done]
    assert order == sorted(order)
    if bounded:  # every forged header is rejected on its own (unbounded, a 2 kB candidate
        # spans the next forged headers, which are skipped with the frames found inside it)
        assert parser.stats.bad_frames >= n_fake - len(lost) - 3 * n_fake / 256 - 3
    else:
        assert parser.stats.bad_frames > 0
    bound = (mtdata2_max_len(output_configuration(XsensConfig(port="x"))) if bounded else 2048) + 7
    assert parser.buffered <= bound


def test_bounded_parser_rejects_long_header_on_its_length_byte() -> None:
    """With the driver's bound the forged header is rejected once its 4th byte is in."""
    p = _bounded()
    assert p.feed(bytes.fromhex("FA FF 36 FF")) == []
    assert p.stats.bad_frames == 1 and p.buffered == 0
    pkt = _packet(7, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert p.feed(bytes.fromhex("07 FF") + pkt) == [(0x36, pkt[4:-1])]
    assert p.stats.bytes_skipped == 6


def test_inner_frame_of_a_genuine_frame_does_not_cost_the_outer_one() -> None:
    """A genuine frame carrying a complete GoToConfigAck in an unknown item, fed byte by
    byte: the look-ahead returns the inner message, the outer one follows when complete."""
    inner = _msg(0x31, b"")
    outer = _msg(0x36, struct.pack(">HB", 0x7777, len(inner)) + inner)
    p = XbusParser()
    got = []
    for b in outer:
        got += [_msg(m, d) for m, d in p.feed(bytes((b,)))]
    assert got == [inner, outer]
    assert p.stats.bad_frames == 0 and p.stats.bytes_skipped == 0 and p.buffered == 0
    # fed at once there is nothing pending: only the outer frame
    q = XbusParser()
    assert [_msg(m, d) for m, d in q.feed(outer)] == [outer]


def _truncated_with_lucky_checksum(nxt: bytes) -> bytes:
    """The first half of a packet whose claimed length runs into ``nxt`` and whose bytes up
    to that end sum to a valid checksum: the one-in-256 case of a truncated frame."""
    whole = _packet(7, (0.1, 0.2, 0.3, 0.4), (0.0, 0.0, 0.0))
    half = bytearray(whole[:len(whole) // 2])
    end = 4 + whole[3] + 1                          # the claimed frame's end, inside nxt
    assert len(half) < end < len(half) + len(nxt)
    claimed = bytes(half) + nxt[:end - len(half)]
    half[-1] = (half[-1] - sum(claimed[1:])) & 0xFF  # one damaged byte makes it checksum-valid
    return bytes(half)


@pytest.mark.parametrize("validated", [True, False])
def test_checksum_valid_false_frame_does_not_swallow_the_next_packet(validated: bool) -> None:
    """Xbus checks with one byte, so a truncated frame followed by a genuine one is
    checksum-valid by chance once in 256. The MTData2 structure check rejects it and the
    genuine packet inside its claimed length is still returned; without it, it is lost."""
    nxt = _packet(9, (0.5, 0.5, 0.5, 0.5), (0.1, 0.2, 0.3))
    after = _packet(10, (0.5, 0.5, 0.5, 0.5), (0.1, 0.2, 0.3))
    stream = _packet(6, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0)) + _truncated_with_lucky_checksum(nxt) + nxt + after
    for chunk in (len(stream), 1, 7):
        p = XbusParser(validators={0x36: mtdata2_well_formed} if validated else None)
        got = []
        for i in range(0, len(stream), chunk):
            got += p.feed(stream[i:i + chunk])
        counters = []
        for _, d in got:
            try:
                counters.append(parse_mtdata2(d).packet_counter)
            except ProtocolError:
                counters.append(None)
        if validated:
            assert counters == [6, 9, 10], chunk
            assert p.stats.bad_frames == 1
        else:
            assert counters == [6, None, 10], chunk


def test_mtdata2_structure_check() -> None:
    good = _packet(1, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))[4:-1]
    assert mtdata2_well_formed(good) and mtdata2_well_formed(b"")
    assert not mtdata2_well_formed(good[:-1])          # last item overruns
    assert not mtdata2_well_formed(good + b"\x10\x20")  # trailing bytes shorter than an item header
    assert not mtdata2_well_formed(good + b"\x10\x20\x05\x00")  # item claims more than is there


def test_random_bytes_exact_byte_accounting() -> None:
    """1 MB of random bytes: never raises, buffer bounded, every byte is either in a returned
    frame, skipped or still buffered."""
    rng = random.Random(5)
    blob = rng.randbytes(1 << 20)
    for parser in (XbusParser(), _bounded()):
        n_frames = 0
        i = 0
        while i < len(blob):
            k = rng.randint(1, 4096)
            for mid, data in parser.feed(blob[i:i + k]):
                n_frames += len(_msg(mid, data))
            i += k
        assert parser.buffered <= 2055
        # look-ahead frames inside an accepted outer frame are counted once by the parser,
        # twice by this sum: so <=, with equality when no outer frame contained an inner one
        assert parser.stats.bytes_skipped + parser.buffered <= len(blob)
        assert parser.stats.bytes_skipped + parser.buffered >= len(blob) - n_frames


def test_garbage_without_preamble_is_skipped_exactly() -> None:
    rng = random.Random(9)
    p = XbusParser()
    frames, skipped = [], 0
    for c in range(2000):
        g = bytes(b for b in rng.randbytes(rng.randint(0, 30)) if b != 0xFA)
        skipped += len(g)
        f = _packet(c, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        frames.append(g + f)
    got = []
    blob = b"".join(frames)
    for i in range(0, len(blob), 37):
        got += p.feed(blob[i:i + 37])
    assert len(got) == 2000
    assert p.stats.bytes_skipped == skipped
    assert p.stats.bad_frames == 0


def test_bounds_are_checked() -> None:
    with pytest.raises(ProtocolError, match="2049"):
        XbusParser(max_data_len=2049)
    with pytest.raises(ProtocolError, match="MID 256"):
        XbusParser(limits={256: 10})


# --------------------------------------------------------------------------- load cells

def _lc_frame(vals: tuple[float, ...]) -> bytes:
    body = struct.pack(">4f", *vals)
    return b"\xAA" + body + bytes((sum(body) & 0xFF, 0x55))


def _lc_fake(rng: random.Random) -> bytes:
    """Start and end byte in place, checksum wrong: a frame-shaped lie."""
    body = rng.randbytes(16)
    return b"\xAA" + body + bytes(((sum(body) + rng.randint(1, 255)) & 0xFF, 0x55))


def test_loadcell_adversarial_frames_delay_no_genuine_frame() -> None:
    """20 000 frames; before every 3rd one a fake frame (start/end bytes right, checksum
    wrong), a lone start byte or random bytes; values that contain 0xAA and 0x55. Every
    genuine frame is returned in the feed that completes it (up to chance checksum hits)."""
    rng = random.Random(11)
    aa = struct.unpack(">f", bytes.fromhex("AA 55 AA 55"))[0]
    parts: list[tuple[bytes, bool]] = []
    n_adv = 0
    for c in range(20_000):
        if c % 3 == 0:
            kind = c % 4
            adv = (_lc_fake(rng), b"\xAA", rng.randbytes(rng.randint(1, 40)), _lc_fake(rng)[:10])[kind]
            parts.append((adv, False))
            n_adv += 1
        vals = (aa, rng.uniform(-2, 2), float(c), -aa) if c % 2 else (rng.uniform(-2, 2),) * 4
        parts.append((_lc_frame(vals), True))
    p = LoadCellParser()
    got, done = _play(p, parts, rng, 60)
    genuine = [b for b, g in parts if g]
    out_at: dict[bytes, int] = {}
    for vals, k in got:
        out_at.setdefault(_lc_frame(vals), k)
    lost = [f for f in genuine if f not in out_at]
    assert len(lost) <= 3 * n_adv / 256 + 3
    assert [f for f in genuine if f in out_at and out_at[f] > done[f]] == []
    assert p.buffered < FRAME_LEN
    assert p.stats.bytes_skipped == sum(len(b) for b in (x for x, _ in parts)) - FRAME_LEN * len(got) - p.buffered


def test_loadcell_random_bytes_never_raise() -> None:
    rng = random.Random(12)
    p = LoadCellParser()
    blob = rng.randbytes(1 << 20)
    n = 0
    for i in range(0, len(blob), 997):
        n += len(p.feed(blob[i:i + 997]))
    assert p.buffered < FRAME_LEN
    assert p.stats.bytes_skipped == len(blob) - FRAME_LEN * n - p.buffered


# --------------------------------------------------------------------------- through the pty

def _start_with_sim(imu, sim) -> None:
    import threading
    import time

    err: list[BaseException] = []

    def run() -> None:
        try:
            imu.start()
        except BaseException as exc:  # re-raised below
            err.append(exc)

    t = threading.Thread(target=run)
    t.start()
    while t.is_alive():
        sim.service()
        time.sleep(0.0005)
    t.join()
    if err:
        raise err[0]


@pytest.mark.parametrize("fake", FAKE_HEADERS[:3], ids=["ext-2047", "ext-2048", "std-254"])
def test_forged_header_written_into_the_pty_costs_no_sample(fake: bytes) -> None:
    """Bytes written into the simulated MTi's pty from outside the simulator: the packet
    emitted right after the forged header is the next sample the driver returns."""
    import time

    from capstan.drivers.serial.xsens import XsensImu
    from capstan.drivers.sim.serial_devices import SimXsens, open_pty_pair

    pty = open_pty_pair()
    imu = XsensImu(XsensConfig.from_mapping({"port": pty.slave_path, "timeout_s": 0.3}))
    sim = SimXsens(pty.master_fd)
    try:
        _start_with_sim(imu, sim)
        import os

        for k in range(20):
            if k == 10:
                os.write(pty.master_fd, fake)
            c = sim.packet_counter
            sim.emit(k / 400, 0.1 * k, 0.0)
            deadline = time.monotonic() + 0.5
            got = None
            while got is None and time.monotonic() < deadline:
                got = imu.poll()
                time.sleep(0.0002)
            assert got is not None and got.counter == c, (k, got)
        assert imu.stats.bad_frames >= 1
        assert imu.stats.bytes_skipped >= len(fake)
    finally:
        imu.close()
        pty.close()
