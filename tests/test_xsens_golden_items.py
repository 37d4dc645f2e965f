"""Every item of the reference's golden MTi-300 packets, against the reference decoder's own text.

The expected values are parsed from the "Decoded Info" lines of
/work/shared/reference/xsens-mti300-golden-packets.md (copied verbatim into
tests/data/xsens_mti300_golden.yaml), i.e. the Xsens MT Manager decoder's output,
not from capstan. MT Manager prints 8 decimals, so floats agree within 5e-9.
"""

from __future__ import annotations

import re
import struct
from pathlib import Path

import pytest
import yaml

from capstan.drivers.serial.xsens_protocol import MtData2, Xdi, parse_mtdata2, xdi_name

GOLDEN = yaml.safe_load((Path(__file__).parent / "data" / "xsens_mti300_golden.yaml").read_text())

#: reference decoder's item names -> XDI type
NAMES = {"PacketCounter": Xdi.PACKET_COUNTER, "SampleTimeFine": Xdi.SAMPLE_TIME_FINE,
         "Quaternion": Xdi.QUATERNION, "Acceleration": Xdi.ACCELERATION, "DeltaV": Xdi.DELTA_V,
         "FreeAcceleration": Xdi.FREE_ACCELERATION, "RateOfTurn": Xdi.RATE_OF_TURN, "DeltaQ": Xdi.DELTA_Q,
         "MagneticField": Xdi.MAGNETIC_FIELD, "Temperature": Xdi.TEMPERATURE,
         "BaroPressure": Xdi.BARO_PRESSURE, "StatusWord": Xdi.STATUS_WORD}
FORMATS = {"Float": 0x0, "ENU": 0x0, "NED": 0x4, "NWU": 0x8, "Double": 0x3, "Fp1220": 0x1, "Fp1632": 0x2}


def _top_level_items(decoded: str) -> list[str]:
    """'{(a, ..), (b, (..)), ...}' -> ['a, ..', 'b, (..)', ...] (split at depth-1 commas)."""
    body = decoded.strip()[1:-1]
    items, depth, cur = [], 0, ""
    for ch in body:
        if ch == "(":
            depth += 1
            if depth == 1:
                cur = ""
                continue
        elif ch == ")":
            depth -= 1
            if depth == 0:
                items.append(cur)
                continue
        if depth >= 1:
            cur += ch
    return items


def reference_items(decoded: str) -> list[tuple[int, int, object]]:
    """(full XDI, size in bytes, value) of each item of a "Decoded Info" line."""
    out = []
    for text in _top_level_items(decoded):
        name, size, value = (s.strip() for s in text.split(",", 2))
        kind, *fmt = name.split("|")
        xdi = int(NAMES[kind]) | sum(FORMATS[f] for f in fmt)
        n = int(size.split()[0])
        if kind == "StatusWord":
            val: object = int(value, 2)
        elif kind in ("PacketCounter", "SampleTimeFine"):
            val = int(value)
        elif kind == "BaroPressure":
            val = int(value.split(":")[1])
        else:
            val = [float(v) for v in re.findall(r":\s*(-?\d+\.\d+)", value)]
        out.append((xdi, n, val))
    return out


def _raw_items(data: bytes) -> list[tuple[int, int]]:
    """(XDI, size) of each item, walked from the MT protocol layout with struct."""
    i, out = 0, []
    while i < len(data):
        xdi, n = struct.unpack_from(">HB", data, i)
        out.append((xdi, n))
        i += 3 + n
    return out


def _capstan_value(m: MtData2, xdi: int) -> object:
    slot = {Xdi.PACKET_COUNTER: m.packet_counter, Xdi.SAMPLE_TIME_FINE: m.sample_time_fine,
            Xdi.QUATERNION: m.quaternion, Xdi.RATE_OF_TURN: m.rate_of_turn_rad_s,
            Xdi.STATUS_WORD: m.status_word}.get(xdi & 0xFFF0)
    if slot is not None:
        return slot
    return m.other[xdi]


@pytest.mark.parametrize("pkt", GOLDEN["packets"], ids=[p["name"] for p in GOLDEN["packets"]])
def test_every_item_the_reference_decodes(pkt: dict) -> None:
    data = bytes.fromhex(pkt["data_hex"])
    ref = reference_items(pkt["decoded"])
    # the raw bytes carry exactly the reference's items, in order, with its sizes
    assert _raw_items(data) == [(x, n) for x, n, _ in ref]
    m = parse_mtdata2(data)
    assert m.coord_sys == 0  # Quaternion|Float|ENU
    for xdi, _n, want in ref:
        got = _capstan_value(m, xdi)
        if isinstance(want, list):
            assert list(got) == pytest.approx(want, abs=5.1e-9), xdi_name(xdi)  # type: ignore[arg-type]
        else:
            assert got == want, xdi_name(xdi)
    # every decoded item is one of the reference's (nothing decoded that it does not list)
    assert set(m.other) == {x for x, _, _ in ref} - {Xdi.PACKET_COUNTER, Xdi.SAMPLE_TIME_FINE, Xdi.QUATERNION,
                                                       Xdi.RATE_OF_TURN, Xdi.STATUS_WORD}


def test_reference_covers_the_items_the_issue_names() -> None:
    """Acceleration, DeltaV, free acceleration, DeltaQ, magnetic field, temperature and
    pressure are asserted above at least once each (this guards the parametrisation)."""
    seen = {x & 0xFFF0 for p in GOLDEN["packets"] for x, _, _ in reference_items(p["decoded"])}
    assert {Xdi.ACCELERATION, Xdi.DELTA_V, Xdi.FREE_ACCELERATION, Xdi.DELTA_Q, Xdi.MAGNETIC_FIELD,
            Xdi.TEMPERATURE, Xdi.BARO_PRESSURE} <= seen
    assert sum(len(reference_items(p["decoded"])) for p in GOLDEN["packets"]) == 11 + 10 + 9 + 12 + 11 + 4


def test_saturated_shake_status_word_bits() -> None:
    """Example 5 (high-intensity shake): the reference expects FilterValid low and
    saturation flags set. StatusWord bit 0 self-test, bit 1 FilterValid, bits 8..14
    clipping of accX, accY, accZ, gyrX, gyrY, gyrZ, mag. Set: ClipAccZ and ClipGyrY, and
    the gyro one is physical: |gyrY| = 10.3 rad/s exceeds the MTi-300's 450 deg/s
    (7.85 rad/s) range while |gyrX| = 4.2 and |gyrZ| = 4.5 rad/s stay inside it."""
    m = parse_mtdata2(bytes.fromhex(next(p for p in GOLDEN["packets"] if p["name"] == "Example 5")["data_hex"]))
    assert m.status_word is not None and m.rate_of_turn_rad_s is not None
    assert m.status_word & 0x2 == 0 and m.status_word & 0x1 == 1
    assert m.status_word & 0x7F00 == (1 << 10) | (1 << 12)
    gyr_range = 450 * 3.141592653589793 / 180
    assert [abs(w) > gyr_range for w in m.rate_of_turn_rad_s] == [False, True, False]
