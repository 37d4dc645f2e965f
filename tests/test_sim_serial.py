"""Simulated serial devices on a real pty: byte-level conversation, fault injection."""

from __future__ import annotations

import math
import os
import select
import struct
import time
from collections.abc import Iterator

import pytest

from capstan.drivers.serial.loadcell_protocol import LoadCellParser, parse_frame
from capstan.drivers.sim.serial_devices import PtyPair, SerialFault, SimLoadCellAmp, SimMode, SimXsens, open_pty_pair
from capstan.drivers.serial.xsens_protocol import Mid, XbusParser, build_message, parse_mtdata2


@pytest.fixture
def pty() -> Iterator[PtyPair]:
    p = open_pty_pair()
    yield p
    p.close()


def _host_read(fd: int, n_min: int, timeout_s: float = 1.0) -> bytes:
    """Read at least n_min bytes from the host side (slave fd)."""
    out = b""
    deadline = time.monotonic() + timeout_s
    while len(out) < n_min and time.monotonic() < deadline:
        r, _, _ = select.select([fd], [], [], 0.02)
        if r:
            out += os.read(fd, 65536)
    return out


def _exchange(sim: SimXsens, pty: PtyPair, request: bytes, n_reply: int) -> bytes:
    os.write(pty.slave_fd, request)
    deadline = time.monotonic() + 1.0
    while not sim.host_mids or not select.select([pty.slave_fd], [], [], 0)[0]:
        sim.service()
        if time.monotonic() > deadline:
            break
    return _host_read(pty.slave_fd, n_reply)


def test_pty_is_raw_8bit_clean(pty: PtyPair) -> None:
    data = bytes(range(256)) * 4  # includes CR, LF, ^C, ^D, XON/XOFF, 0xFF
    os.write(pty.master_fd, data)
    assert _host_read(pty.slave_fd, len(data)) == data
    os.write(pty.slave_fd, data)
    got = b""
    deadline = time.monotonic() + 1.0
    while len(got) < len(data) and time.monotonic() < deadline:
        try:
            got += os.read(pty.master_fd, 65536)
        except BlockingIOError:
            time.sleep(0.001)
    assert got == data


def test_handshake_bytes_exact(pty: PtyPair) -> None:
    sim = SimXsens(pty.master_fd)
    assert sim.mode == SimMode.MEASUREMENT
    assert _exchange(sim, pty, bytes.fromhex("FA FF 30 00 D1"), 5) == bytes.fromhex("FA FF 31 00 D0")
    assert sim.mode == SimMode.CONFIG
    # SetOutputConfiguration: PacketCounter, SampleTimeFine, Quaternion fp16.32 NED @ 100 Hz,
    # RateOfTurn fp16.32 @ 100 Hz, StatusWord; checksum computed by hand
    req = bytes.fromhex("FA FF C0 14 10 20 FF FF 10 60 FF FF 20 16 00 64 80 22 00 64 E0 20 FF FF F3")
    sim.host_mids.clear()
    reply = _exchange(sim, pty, req, len(req))
    # the ack (MID 0xC1) echoes the configuration
    assert reply == bytes.fromhex("FA FF C1 14 10 20 FF FF 10 60 FF FF 20 16 00 64 80 22 00 64 E0 20 FF FF F2")
    assert sim.output_rate_hz == 100
    sim.host_mids.clear()
    assert _exchange(sim, pty, bytes.fromhex("FA FF 10 00 F1"), 5) == bytes.fromhex("FA FF 11 00 F0")
    assert sim.mode == SimMode.MEASUREMENT


def test_unsupported_requests_get_error_0x42(pty: PtyPair) -> None:
    sim = SimXsens(pty.master_fd)
    # unknown MID (ReqFWRev is not implemented by the simulated device): InvalidMessage (4)
    assert _exchange(sim, pty, bytes.fromhex("FA FF 12 00 EF"), 6) == build_message(Mid.ERROR, b"\x04")
    # SetOutputConfiguration in measurement mode: InvalidMessage
    sim.host_mids.clear()
    req = build_message(Mid.SET_OUTPUT_CONFIGURATION, bytes.fromhex("10 20 FF FF"))
    assert _exchange(sim, pty, req, 6) == build_message(Mid.ERROR, b"\x04")
    # unsupported data identifier (Acceleration) in config mode: InvalidParam (33)
    sim.host_mids.clear()
    _exchange(sim, pty, build_message(Mid.GO_TO_CONFIG), 5)
    sim.host_mids.clear()
    req = build_message(Mid.SET_OUTPUT_CONFIGURATION, bytes.fromhex("40 20 01 90"))
    assert _exchange(sim, pty, req, 6) == build_message(Mid.ERROR, bytes((33,)))
    # ReqDID answers with the device id
    sim.host_mids.clear()
    assert _exchange(sim, pty, build_message(Mid.REQ_DID), 9) == build_message(Mid.DEVICE_ID, bytes.fromhex("037003F8"))


@pytest.mark.parametrize("axis,sign,offset", [("x", 1.0, 0.0), ("y", -1.0, 0.3), ("z", 1.0, -1.0)])
def test_emit_packet_content(pty: PtyPair, axis: str, sign: float, offset: float) -> None:
    sim = SimXsens(pty.master_fd, joint_axis=axis, sign=sign, offset_rad=offset)
    q_out, dq_out = 0.7, -2.5
    assert sim.emit(1.25, q_out, dq_out)
    msgs = XbusParser().feed(_host_read(pty.slave_fd, 58))
    assert len(msgs) == 1 and msgs[0][0] == Mid.MT_DATA2
    m = parse_mtdata2(msgs[0][1])
    assert m.packet_counter == 0
    assert m.sample_time_fine == 12500
    assert m.status_word == 3
    a = "xyz".index(axis)
    twist = sign * (q_out - offset)
    q_expected = [math.cos(twist / 2), 0.0, 0.0, 0.0]
    q_expected[1 + a] = math.sin(twist / 2)
    assert m.quaternion == pytest.approx(q_expected, abs=1e-7)
    w = [0.0, 0.0, 0.0]
    w[a] = sign * dq_out
    assert m.rate_of_turn_rad_s == pytest.approx(w, abs=1e-6)


def test_no_stream_in_config_mode(pty: PtyPair) -> None:
    sim = SimXsens(pty.master_fd)
    _exchange(sim, pty, build_message(Mid.GO_TO_CONFIG), 5)
    assert not sim.emit(0.0, 0.0, 0.0)
    assert _host_read(pty.slave_fd, 1, timeout_s=0.05) == b""


def test_xsens_fault_injection(pty: PtyPair) -> None:
    sim = SimXsens(pty.master_fd, seed=1)
    sim.inject_fault(SerialFault.CORRUPT_CHECKSUM)
    sim.inject_fault(SerialFault.TRUNCATE)
    sim.inject_fault(SerialFault.GARBAGE)
    sim.inject_fault(SerialFault.DROP_COUNTER)
    for k in range(6):
        sim.emit(k * 0.0025, 0.1 * k, 0.0)
    p = XbusParser()
    # read until the stream is quiet: the faults add bytes, so a byte count would stop
    # short of the last frame when the pty delivers in pieces
    data, chunk = b"", b"x"
    while chunk:
        chunk = _host_read(pty.slave_fd, 1, timeout_s=0.2)
        data += chunk
    msgs = p.feed(data)
    counters = [parse_mtdata2(d).packet_counter for _, d in msgs]
    # frames 0 (bad checksum) and 1 (truncated) lost; 2 after garbage kept;
    # frame 3 skips counter value 3
    assert counters == [2, 4, 5, 6]
    assert p.stats.bad_frames >= 2


def test_loadcell_amp_inverse_scaling_and_faults(pty: PtyPair) -> None:
    amp = SimLoadCellAmp(pty.master_fd, scale_N_per_mV_V=(200.0, 250.0, 300.0, 400.0),
                         offset_N=(1.0, -2.0, 0.0, 5.0), bias_mV_V=(0.01, 0.0, 0.0, -0.02), seed=3)
    amp.emit((120.0, 110.0, 100.0, 90.0))
    raw = parse_frame(_host_read(pty.slave_fd, 19))
    assert raw == pytest.approx([(120 - 1) / 200 + 0.01, (110 + 2) / 250, 100 / 300, (90 - 5) / 400 - 0.02],
                                rel=1e-6)
    amp.inject_fault(SerialFault.CORRUPT_CHECKSUM)
    amp.inject_fault(SerialFault.GARBAGE)
    amp.inject_fault(SerialFault.TRUNCATE)
    for _ in range(5):
        amp.emit((1.0, 2.0, 3.0, 4.0))
    p = LoadCellParser()
    p.feed(struct.pack(">B", 0))  # parser starts hunting
    frames = p.feed(_host_read(pty.slave_fd, 19 * 4))
    assert len(frames) == 3  # garbage-prefixed frame and the last two


def _set_host_rate(pty: PtyPair, baudrate: int) -> None:
    import termios

    attrs = termios.tcgetattr(pty.slave_fd)
    attrs[4] = attrs[5] = getattr(termios, f"B{baudrate}")
    termios.tcsetattr(pty.slave_fd, termios.TCSANOW, attrs)


def test_new_unit_answers_only_at_its_boot_rate_and_moves_on_reset(pty: PtyPair) -> None:
    """Bytes of the MT protocol (hand-written): a unit booting at 115200 Bd ignores a
    GoToConfig sent at 921600 (and the host sees no preamble), answers at 115200; SetBaudrate
    0x80 (921600) is acknowledged (FA FF 19 00 E8) and applied at Reset: ResetAck at the old
    rate, WakeUp (FA FF 3E 00 C3) at the new one after the reboot."""
    sim = SimXsens(pty.master_fd, boot_baudrate=115200)
    sim.mode = SimMode.CONFIG
    _set_host_rate(pty, 921600)
    os.write(pty.slave_fd, bytes.fromhex("FA FF 30 00 D1"))
    for _ in range(20):
        sim.service()
    sim.emit(0.0, 0.0, 0.0)  # config mode: nothing; the line carries no frame either way
    assert sim.host_mids == [] and sim.garbled_bytes == 5
    _set_host_rate(pty, 115200)
    assert _exchange(sim, pty, bytes.fromhex("FA FF 30 00 D1"), 5) == bytes.fromhex("FA FF 31 00 D0")
    assert _exchange(sim, pty, bytes.fromhex("FA FF 18 01 80 68"), 5) == bytes.fromhex("FA FF 19 00 E8")
    assert sim.baudrate == 115200 and sim.stored_baudrate == 921600
    assert _exchange(sim, pty, bytes.fromhex("FA FF 40 00 C1"), 5) == bytes.fromhex("FA FF 41 00 C0")
    _set_host_rate(pty, 921600)
    deadline = time.monotonic() + 1.0
    while not select.select([pty.slave_fd], [], [], 0)[0] and time.monotonic() < deadline:
        sim.service()
        time.sleep(0.002)
    assert _host_read(pty.slave_fd, 5) == bytes.fromhex("FA FF 3E 00 C3")
    assert sim.baudrate == 921600 and sim.mode == SimMode.MEASUREMENT
    # an unknown rate code is refused with Error 0x42 BAUDRATE_INVALID (32 = 0x20)
    _exchange(sim, pty, bytes.fromhex("FA FF 30 00 D1"), 5)
    assert _exchange(sim, pty, bytes.fromhex("FA FF 18 01 77 71"), 6) == bytes.fromhex("FA FF 42 01 20 9E")


def test_req_output_configuration_returns_the_stored_configuration(pty: PtyPair) -> None:
    sim = SimXsens(pty.master_fd)
    _exchange(sim, pty, bytes.fromhex("FA FF 30 00 D1"), 5)
    want = bytes.fromhex("10 20 FF FF 10 60 FF FF 20 10 01 90 80 20 01 90 E0 20 FF FF")
    reply = _exchange(sim, pty, bytes.fromhex("FA FF C0 00 41"), 4 + len(want) + 1)
    assert reply == build_message(Mid.OUTPUT_CONFIGURATION, want)
