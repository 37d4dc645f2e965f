"""Byte-level conversations of the Xsens driver's start-up with a scripted port: the exact
bytes it writes (checksums worked by hand), the reference document's acknowledgement, the
output-configuration read-back naming what the controller lacks, and the stream bound that
follows the read-back."""

from __future__ import annotations

import re

import pytest

from capstan.drivers.serial.xsens import XsensConfig, XsensImu
from capstan.drivers.serial.xsens_protocol import Mid, build_message, encode_output_configuration
from capstan.models.common.errors import ProtocolError


class ScriptedPort:
    """A fake pyserial port that records writes and answers with canned replies."""

    def __init__(self, replies: dict[int, bytes]) -> None:
        self.replies = replies
        self.written: list[bytes] = []
        self._rx = bytearray()
        self.timeout = 0
        self.baudrate = 921600

    @property
    def in_waiting(self) -> int:
        return len(self._rx)

    def write(self, data: bytes) -> int:
        """Answer by (MID, length byte) if scripted so, else by MID."""
        self.written.append(bytes(data))
        self._rx += self.replies.get((data[2], data[3]), self.replies.get(data[2], b""))  # type: ignore[call-overload]
        return len(data)

    def read(self, n: int) -> bytes:
        out = bytes(self._rx[:n])
        del self._rx[:n]
        return out

    def reset_input_buffer(self) -> None:
        self._rx.clear()

    def close(self) -> None:
        pass


def test_exact_bytes_written_by_driver() -> None:
    cfg = XsensConfig(port="scripted")
    echo = bytes.fromhex("10 20 FF FF 10 60 FF FF 20 10 01 90 80 20 01 90 E0 20 FF FF")
    port = ScriptedPort({0x30: bytes.fromhex("FA FF 31 00 D0"),
                         0xC0: build_message(Mid.OUTPUT_CONFIGURATION, echo),
                         0x10: bytes.fromhex("FA FF 11 00 F0")})
    XsensImu(cfg, port=port).start()
    assert port.written == [
        bytes.fromhex("FA FF 30 00 D1"),
        # PacketCounter, SampleTimeFine, Quaternion float32 ENU @400, RateOfTurn float32 @400,
        # StatusWord; checksum by hand: sum(FF..FF) = 0xB5F -> CS = 0xA1
        bytes.fromhex("FA FF C0 14 10 20 FF FF 10 60 FF FF 20 10 01 90 80 20 01 90 E0 20 FF FF A1"),
        bytes.fromhex("FA FF C0 00 41"),  # ReqOutputConfiguration: the read-back
        bytes.fromhex("FA FF 10 00 F1"),
    ]


#: the reference document's own acknowledgement of its 12-item SetOutputConfiguration
REFERENCE_C1 = bytes.fromhex("FA FF C1 08 10 20 FF FF 10 60 FF FF 9C")


def _scripted(readback: list[tuple[int, int]]) -> ScriptedPort:
    return ScriptedPort({0x30: bytes.fromhex("FA FF 31 00 D0"),
                         (0xC0, 0x14): REFERENCE_C1,
                         (0xC0, 0x00): build_message(Mid.OUTPUT_CONFIGURATION,
                                                     encode_output_configuration(readback)),
                         0x10: bytes.fromhex("FA FF 11 00 F0")})


def test_start_passes_on_the_reference_acknowledgement_bytes() -> None:
    """The 0xC1 reply of the reference (2 items answering a 12-item request) is accepted;
    the read-back decides. A device reporting 2000 Hz for 'every packet' items passes."""
    assert sum(REFERENCE_C1[1:]) & 0xFF == 0
    readback = [(0x1020, 2000), (0x1060, 0xFFFF), (0x2010, 400), (0x8020, 400), (0xE020, 0),
                (0xC020, 100)]  # an extra item (magnetic field) is allowed
    imu = XsensImu(XsensConfig(port="scripted"), port=_scripted(readback))
    imu.start()
    assert imu.output_readback == readback and imu.found_baudrate == 921600


@pytest.mark.parametrize("readback, named", [
    ([(0x1020, 0xFFFF), (0x1060, 0xFFFF)], "QUATERNION|FLOAT32|ENU at 400 Hz is missing; "
                                           "RATE_OF_TURN|FLOAT32 at 400 Hz is missing"),
    ([(0x1020, 0xFFFF), (0x1060, 0xFFFF), (0x2010, 100), (0x8020, 400), (0xE020, 0xFFFF)],
     "QUATERNION|FLOAT32|ENU is at 100 Hz, the controller needs 400 Hz"),
    ([(0x1020, 0xFFFF), (0x1060, 0xFFFF), (0x2014, 400), (0x8020, 400), (0xE020, 0xFFFF)],
     "QUATERNION|FLOAT32|ENU at 400 Hz is missing (the device sends QUATERNION|FLOAT32|NED)"),
    ([(0x1020, 0xFFFF), (0x1060, 0xFFFF), (0x2010, 400), (0x8020, 400), (0xE020, 100)],
     "STATUS_WORD is at 100 Hz, the controller needs every packet"),
])
def test_readback_lacking_what_the_controller_needs_is_named(readback: list, named: str) -> None:
    with pytest.raises(ProtocolError, match=re.escape(named)):
        XsensImu(XsensConfig(port="scripted"), port=_scripted(readback)).start()


def test_stream_bound_follows_the_readback_including_extra_items() -> None:
    """The device also sends MagneticField (reported by the read-back): its packets, 15
    bytes longer than the requested output, are accepted; a forged longer header is not."""
    from capstan.drivers.serial.xsens_protocol import build_mtdata2_item, encode_values

    readback = [(0x1020, 0xFFFF), (0x1060, 0xFFFF), (0x2010, 400), (0x8020, 400), (0xE020, 0xFFFF),
                (0xC020, 400)]
    port = _scripted(readback)
    imu = XsensImu(XsensConfig(port="scripted"), port=port)
    imu.start()
    data = b"".join([
        build_mtdata2_item(0x1020, (7).to_bytes(2, "big")), build_mtdata2_item(0x1060, (70).to_bytes(4, "big")),
        build_mtdata2_item(0x2010, encode_values((1.0, 0.0, 0.0, 0.0), 0)),
        build_mtdata2_item(0x8020, encode_values((0.0, 0.0, 0.5), 0)),
        build_mtdata2_item(0xE020, (3).to_bytes(4, "big")),
        build_mtdata2_item(0xC020, encode_values((0.1, 0.2, 0.3), 0))])
    assert len(data) == 53 + 15
    port._rx += bytes.fromhex("FA FF 36 45") + build_message(Mid.MT_DATA2, data)  # 0x45 = 69 > 68: forged
    s = imu.poll()
    assert s is not None and s.counter == 7 and s.dq_out_rad_s == pytest.approx(0.5)
    assert imu.stats.bad_frames == 1 and imu.stats.bytes_skipped == 4
