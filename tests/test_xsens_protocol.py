"""Xsens MT protocol: golden device bytes, exact host bytes, number formats, fuzzing."""

from __future__ import annotations

import random
import struct
from pathlib import Path

import pytest
import yaml

from capstan.drivers.serial.xsens_protocol import (
    Mid, Precision, XbusParser, Xdi, build_message, build_mtdata2_item, checksum,
    decode_output_configuration, decode_values, encode_output_configuration, encode_values,
    parse_mtdata2,
)
from capstan.models.common.errors import ProtocolError

GOLDEN = yaml.safe_load((Path(__file__).parent / "data" / "xsens_mti300_golden.yaml").read_text())


def _hex(s: str) -> bytes:
    return bytes.fromhex(s)


# --------------------------------------------------------------------------- golden bytes

@pytest.mark.parametrize("pkt", GOLDEN["packets"], ids=[p["name"] for p in GOLDEN["packets"]])
def test_golden_mtdata2_decodes_to_documented_values(pkt: dict) -> None:
    data = _hex(pkt["data_hex"])
    parser = XbusParser()
    msgs = parser.feed(build_message(Mid.MT_DATA2, data))
    assert msgs == [(Mid.MT_DATA2, data)]
    m = parse_mtdata2(msgs[0][1])
    assert m.packet_counter == pkt["packet_counter"]
    assert m.sample_time_fine == pkt["sample_time_fine"]
    # MT Manager prints 8 decimals: rounding error <= 5e-9
    assert m.quaternion == pytest.approx(pkt["quaternion"], abs=5.1e-9)
    if "rate_of_turn_rad_s" in pkt:
        assert m.rate_of_turn_rad_s == pytest.approx(pkt["rate_of_turn_rad_s"], abs=5.1e-9)
    assert m.status_word == int(pkt["status_word_bits"], 2)
    assert m.coord_sys == 0  # ENU
    assert parser.stats.bad_frames == 0


def test_golden_packet_with_temperature_and_pressure() -> None:
    pkt = next(p for p in GOLDEN["packets"] if p["name"] == "Example 4")
    m = parse_mtdata2(_hex(pkt["data_hex"]))
    assert m.other[Xdi.TEMPERATURE] == (37.625,)
    assert m.other[Xdi.BARO_PRESSURE] == 100065


@pytest.mark.parametrize("name", sorted(GOLDEN["host_messages"]))
def test_golden_host_messages_have_valid_checksum(name: str) -> None:
    raw = _hex(GOLDEN["host_messages"][name])
    assert sum(raw[1:]) & 0xFF == 0


def test_host_command_bytes_exact() -> None:
    assert build_message(Mid.GO_TO_CONFIG) == _hex("FA FF 30 00 D1")
    assert build_message(Mid.GO_TO_MEASUREMENT) == _hex("FA FF 10 00 F1")
    assert build_message(Mid.INIT_MT) == _hex("FA FF 02 00 FF")
    assert build_message(Mid.REQ_FW_REV) == _hex("FA FF 12 00 EF")
    golden = _hex(GOLDEN["host_messages"]["set_output_configuration"])
    items = decode_output_configuration(golden[4:-1])
    assert items[:3] == [(0x1020, 0xFFFF), (0x1060, 0xFFFF), (0x2010, 400)]
    assert items[-1] == (0xE020, 0xFFFF)
    assert build_message(Mid.SET_OUTPUT_CONFIGURATION, encode_output_configuration(items)) == golden


def test_device_replies_parse() -> None:
    dev = GOLDEN["device_messages"]
    blob = b"".join(_hex(dev[k]) for k in ("go_to_config_ack", "output_configuration", "init_mt_results"))
    msgs = XbusParser().feed(blob)
    assert [m for m, _ in msgs] == [Mid.GO_TO_CONFIG_ACK, Mid.OUTPUT_CONFIGURATION, Mid.INIT_MT_RESULTS]
    assert decode_output_configuration(msgs[1][1]) == [(0x1020, 0xFFFF), (0x1060, 0xFFFF)]
    assert msgs[2][1] == _hex("03 70 03 F8")


def test_extended_length_message() -> None:
    data = bytes(range(256)) + bytes(44)  # 300 bytes
    raw = build_message(Mid.MT_DATA2, data)
    assert raw[:6] == _hex("FA FF 36 FF 01 2C")
    assert len(raw) == 6 + 300 + 1
    assert sum(raw[1:]) & 0xFF == 0
    parser = XbusParser()
    # byte by byte: the parser must wait for the whole extended frame
    out = []
    for b in raw:
        out += parser.feed(bytes((b,)))
    assert out == [(Mid.MT_DATA2, data)]
    with pytest.raises(ProtocolError):
        build_message(Mid.MT_DATA2, bytes(2049))


def test_extended_length_out_of_range_is_bad_frame() -> None:
    body = bytes((0xFF, 0x36, 0xFF, 0x00, 0x10))  # EXT_LEN 16 < 255: invalid
    bad = bytes((0xFA,)) + body + bytes(16) + bytes((checksum(body),))
    good = build_message(Mid.GO_TO_CONFIG_ACK)
    parser = XbusParser()
    assert parser.feed(bad + good) == [(Mid.GO_TO_CONFIG_ACK, b"")]
    assert parser.stats.bad_frames == 1


# --------------------------------------------------------------------------- numbers

def test_fixed_point_bytes_from_spec() -> None:
    assert encode_values([1.0], Precision.FP1220) == _hex("00 10 00 00")
    assert encode_values([-1.0], Precision.FP1220) == _hex("FF F0 00 00")
    # fp16.32: fraction (4 bytes) first, then integer part (2 bytes)
    assert encode_values([1.0], Precision.FP1632) == _hex("00 00 00 00 00 01")
    assert encode_values([-1.0], Precision.FP1632) == _hex("00 00 00 00 FF FF")
    assert encode_values([0.5], Precision.FP1632) == _hex("80 00 00 00 00 00")
    assert encode_values([-0.5], Precision.FP1632) == _hex("80 00 00 00 FF FF")
    assert encode_values([-1.25], Precision.FP1632) == _hex("C0 00 00 00 FF FE")
    assert decode_values(_hex("C0 00 00 00 FF FE"), Precision.FP1632) == (-1.25,)
    assert decode_values(_hex("FF F0 00 00"), Precision.FP1220) == (-1.0,)
    assert encode_values([1.5], Precision.FLOAT32) == struct.pack(">f", 1.5)
    assert encode_values([1.5], Precision.FLOAT64) == struct.pack(">d", 1.5)


@pytest.mark.parametrize("prec,tol", [(Precision.FLOAT32, 1e-6), (Precision.FP1220, 2 ** -21),
                                      (Precision.FP1632, 2 ** -33), (Precision.FLOAT64, 0.0)])
def test_number_formats_round_trip(prec: Precision, tol: float) -> None:
    rng = random.Random(1)
    vals = [rng.uniform(-2000.0, 2000.0) for _ in range(200)]
    back = decode_values(encode_values(vals, prec), prec)
    for v, b in zip(vals, back):
        assert abs(v - b) <= tol * max(1.0, abs(v) if prec == Precision.FLOAT32 else 1.0)
    with pytest.raises(ProtocolError):
        decode_values(b"\x00" * 5, prec if prec != Precision.FP1632 else Precision.FLOAT32)


@pytest.mark.parametrize("prec", list(Precision))
def test_mtdata2_all_precisions(prec: Precision) -> None:
    q = (0.5, -0.5, 0.5, -0.5)
    w = (0.25, -1.5, 3.0)
    data = (build_mtdata2_item(Xdi.PACKET_COUNTER, struct.pack(">H", 65535))
            + build_mtdata2_item(Xdi.QUATERNION | prec | 0x4, encode_values(q, prec))
            + build_mtdata2_item(Xdi.RATE_OF_TURN | prec, encode_values(w, prec)))
    m = parse_mtdata2(data)
    assert m.packet_counter == 65535
    assert m.quaternion == q and m.rate_of_turn_rad_s == w  # exactly representable
    assert m.coord_sys == 0x4
    e = (10.0, -20.0, 170.0)
    m = parse_mtdata2(build_mtdata2_item(Xdi.EULER_ANGLES | prec, encode_values(e, prec)))
    assert m.euler_deg == e


def test_mtdata2_malformed_raises_protocol_error() -> None:
    with pytest.raises(ProtocolError):  # item overruns message
        parse_mtdata2(_hex("20 10 10 3F 80 00 00"))
    with pytest.raises(ProtocolError):  # quaternion with 3 floats
        parse_mtdata2(build_mtdata2_item(Xdi.QUATERNION, bytes(12)))
    with pytest.raises(ProtocolError):  # packet counter of 4 bytes
        parse_mtdata2(build_mtdata2_item(Xdi.PACKET_COUNTER, bytes(4)))
    with pytest.raises(ProtocolError):  # dangling bytes
        parse_mtdata2(_hex("10 20"))


# --------------------------------------------------------------------------- fuzzing

def _random_frames(rng: random.Random, n: int) -> list[bytes]:
    frames = []
    for _ in range(n):
        if rng.random() < 0.01:
            data = rng.randbytes(rng.randint(255, 400))
        else:
            data = rng.randbytes(rng.randint(0, 60))
        frames.append(build_message(rng.randrange(256), data))
    return frames


def _feed_in_chunks(parser: XbusParser, blob: bytes, rng: random.Random) -> list[tuple[int, bytes]]:
    out = []
    i = 0
    while i < len(blob):
        k = rng.randint(1, 4096)
        out += parser.feed(blob[i:i + k])
        i += k
    return out


def test_fuzz_checksum_errors_and_garbage_exact_accounting() -> None:
    """1e5 frames, 10 % with a wrong checksum, garbage without 0xFA between some:
    every valid frame recovered in order, every corrupted one counted bad."""
    rng = random.Random(42)
    frames = _random_frames(rng, 100_000)
    parts, expected, n_bad = [], [], 0
    for f in frames:
        if rng.random() < 0.05:
            parts.append(bytes(b if b != 0xFA else 0x00 for b in rng.randbytes(rng.randint(1, 30))))
        if rng.random() < 0.10:
            parts.append(f[:-1] + bytes(((f[-1] + rng.randint(1, 255)) & 0xFF,)))
            n_bad += 1
        else:
            parts.append(f)
            expected.append(f)
    parser = XbusParser()
    got = _feed_in_chunks(parser, b"".join(parts), rng)
    assert len(got) == len(expected)
    assert all(build_message(m, d) == f for (m, d), f in zip(got, expected))
    assert parser.stats.bad_frames >= n_bad
    assert parser.stats.resyncs > 0


def test_fuzz_truncation_and_random_garbage_recovers() -> None:
    """1e5 frames with 5 % truncated and 5 % followed by random garbage (any bytes).

    A truncated frame borrows bytes of the next frame; its 8-bit checksum then passes by
    chance with probability 1/256, which can cost the next frame. Bound: lost frames
    <= 3 x (truncations + garbage blobs)/256 + 5.
    """
    rng = random.Random(7)
    frames = _random_frames(rng, 100_000)
    parts, valid, n_trunc, n_garbage = [], [], 0, 0
    for f in frames:
        r = rng.random()
        if r < 0.05:
            # keep at least FA FF: a lone 0xFA cannot be told from garbage
            parts.append(f[:rng.randint(2, len(f) - 1)])
            n_trunc += 1
        else:
            parts.append(f)
            valid.append(f)
        if rng.random() < 0.05:
            parts.append(rng.randbytes(rng.randint(1, 40)))
            n_garbage += 1
    parser = XbusParser()
    got = _feed_in_chunks(parser, b"".join(parts), rng)
    got_set = {build_message(m, d) for m, d in got}
    lost = sum(1 for f in valid if f not in got_set)
    assert lost <= 3 * (n_trunc + n_garbage) / 256 + 5
    assert parser.stats.bad_frames >= n_trunc - lost
    assert parser.buffered <= 2055


def test_fuzz_mtdata2_payloads_only_protocol_errors() -> None:
    """1e5 random MTData2 payloads (random XDIs from the known set and random sizes)."""
    rng = random.Random(3)
    xdis = [int(x) for x in Xdi] + [0x1234, 0xFFFF]
    ok = bad = 0
    for _ in range(100_000):
        data = b"".join(
            struct.pack(">HB", rng.choice(xdis) | rng.randrange(16), k) + rng.randbytes(k)
            for k in (rng.choice((0, 1, 2, 4, 6, 8, 12, 16, 24, 32)) for _ in range(rng.randint(1, 4)))
        )
        if rng.random() < 0.2:
            data = data[:rng.randint(0, len(data))]
        try:
            parse_mtdata2(data)
            ok += 1
        except ProtocolError:
            bad += 1
    assert ok + bad == 100_000 and ok > 0 and bad > 0


def test_checksum_byte_equal_to_preamble_is_not_garbage() -> None:
    # find a message whose checksum byte is 0xFA, then feed it in two calls
    data = next(bytes((k,)) for k in range(256) if build_message(Mid.MT_DATA2, bytes((k,)))[-1] == 0xFA)
    msg = build_message(Mid.MT_DATA2, data)
    parser = XbusParser()
    assert parser.feed(msg) == [(Mid.MT_DATA2, data)]
    assert parser.buffered == 0
    assert parser.feed(msg) == [(Mid.MT_DATA2, data)]
    assert parser.stats.resyncs == 0 and parser.stats.bad_frames == 0
