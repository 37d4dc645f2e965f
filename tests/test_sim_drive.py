"""The simulated CiA 402 drive, byte by byte: a raw bus plays the master (exact CAN frames)."""

from __future__ import annotations

import math

import can
import pytest

from cia402_helpers import CAPSTAN_EDS, NODE_ID, VENDOR_EDS
from capstan.drivers.can_unix import UnixSocketBus
from capstan.drivers.canopen.cia402 import State402
from capstan.drivers.sim.drive import SimDrive

SDO_RX, SDO_TX, EMCY, HB = 0x600 + NODE_ID, 0x580 + NODE_ID, 0x80 + NODE_ID, 0x700 + NODE_ID


@pytest.fixture
def channel(tmp_path):
    return str(tmp_path / "can0")


@pytest.fixture
def master(channel):
    bus = UnixSocketBus(channel)
    yield bus
    bus.shutdown()


@pytest.fixture
def drive(master, channel):
    bus = UnixSocketBus(channel)
    sim = SimDrive(bus, NODE_ID, CAPSTAN_EDS, rated_torque_Nm=2.0)
    boot = master.recv(1.0)
    assert (boot.arbitration_id, bytes(boot.data)) == (HB, b"\x00")  # boot-up frame
    yield sim
    sim.close()
    bus.shutdown()


def send(bus, can_id, data):
    bus.send(can.Message(arbitration_id=can_id, data=bytes(data), is_extended_id=False))


#: frames recv_id() passed over while waiting for another id
SKIPPED: list[tuple[int, bytes]] = []


def recv_id(bus, can_id, timeout=1.0):
    while True:
        msg = bus.recv(timeout)
        assert msg is not None, f"no frame 0x{can_id:03X}"
        if msg.arbitration_id == can_id:
            return bytes(msg.data)
        SKIPPED.append((msg.arbitration_id, bytes(msg.data)))


def sdo(bus, request):
    send(bus, SDO_RX, request)
    return recv_id(bus, SDO_TX)


def drain(bus):
    out = []
    while (m := bus.recv(0.02)) is not None:
        out.append((m.arbitration_id, bytes(m.data)))
    return out


def sdo_write_u16(bus, index, sub, value):
    return sdo(bus, bytes([0x2B, index & 0xFF, index >> 8, sub]) + value.to_bytes(2, "little") + b"\0\0")


def enable_over_sdo(master):
    for cw in (0x06, 0x07, 0x0F):
        assert sdo_write_u16(master, 0x6040, 0, cw)[0] == 0x60


def test_sdo_upload_of_the_device_type(master, drive):
    # 0x1000 = 0x00020192: CiA 402 drive, servo
    assert sdo(master, bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])) == \
        bytes([0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00])


def test_heartbeat_producer_follows_0x1017(master, drive):
    assert sdo(master, bytes([0x2B, 0x17, 0x10, 0x00, 0x0A, 0x00, 0, 0])) == bytes([0x60, 0x17, 0x10, 0x00, 0, 0, 0, 0])
    for k in range(51):
        drive.service(k * 0.001)  # 0 ... 50 ms
    frames = [f for f in drain(master) if f[0] == HB]
    assert frames == [(HB, b"\x7f")] * 6  # at 0, 10, 20, 30, 40, 50 ms; PRE-OPERATIONAL = 0x7F


def test_mode_not_in_0x6502_is_refused_with_an_sdo_abort(master, drive):
    # shipped EDS lists CST only (0x6502 = 0x200): profile torque (4) -> abort 0x06090030
    assert sdo(master, bytes([0x2F, 0x60, 0x60, 0x00, 0x04, 0, 0, 0])) == \
        bytes([0x80, 0x60, 0x60, 0x00, 0x30, 0x00, 0x09, 0x06])
    assert sdo(master, bytes([0x2F, 0x60, 0x60, 0x00, 0x0A, 0, 0, 0]))[0] == 0x60
    assert sdo(master, bytes([0x40, 0x61, 0x60, 0x00, 0, 0, 0, 0])) == bytes([0x4F, 0x61, 0x60, 0x00, 0x0A, 0, 0, 0])


def test_state_machine_over_sdo_controlword(master, drive):
    read_sw = bytes([0x40, 0x41, 0x60, 0x00, 0, 0, 0, 0])
    assert sdo(master, read_sw)[4:6] == (0x0240).to_bytes(2, "little")   # switch on disabled
    sdo_write_u16(master, 0x6040, 0, 0x06)
    assert sdo(master, read_sw)[4:6] == (0x0221).to_bytes(2, "little")   # ready to switch on
    sdo_write_u16(master, 0x6040, 0, 0x07)
    assert sdo(master, read_sw)[4:6] == (0x0233).to_bytes(2, "little")   # switched on
    sdo_write_u16(master, 0x6040, 0, 0x0F)
    assert sdo(master, read_sw)[4:6] == (0x0237).to_bytes(2, "little")   # operation enabled (no mode)
    assert drive.torque_command_Nm == 0.0                                # no torque mode yet


def test_tpdo_on_sync_with_the_mapping_the_master_wrote(master, drive):
    writes = [
        bytes([0x23, 0x00, 0x18, 0x01, 0x83, 0x01, 0x00, 0x80]),  # TPDO1 COB-ID disabled
        bytes([0x2F, 0x00, 0x18, 0x02, 0x01, 0, 0, 0]),           # every SYNC
        bytes([0x2F, 0x00, 0x1A, 0x00, 0x00, 0, 0, 0]),
        bytes([0x23, 0x00, 0x1A, 0x01, 0x10, 0x00, 0x41, 0x60]),  # 0x6041 16 bit
        bytes([0x23, 0x00, 0x1A, 0x02, 0x20, 0x00, 0x64, 0x60]),  # 0x6064 32 bit
        bytes([0x2F, 0x00, 0x1A, 0x00, 0x02, 0, 0, 0]),
        bytes([0x23, 0x00, 0x18, 0x01, 0x83, 0x01, 0x00, 0x00]),  # enabled on 0x183
    ]
    for w in writes:
        assert sdo(master, w)[0] == 0x60
    drive.set_feedback(1.0, 0.0, 0.0)
    send(master, 0x80, b"")
    assert drain(master) == []             # PRE-OPERATIONAL: no PDOs
    send(master, 0x000, bytes([0x01, NODE_ID]))  # NMT start
    send(master, 0x80, b"")
    counts = round(1.0 * (1 << 17) / (2 * math.pi))   # 20861 = 0x517D
    assert counts == 0x517D
    # statusword 0x0240 (switch on disabled, remote), then the position in increments
    assert recv_id(master, 0x183) == bytes([0x40, 0x02]) + counts.to_bytes(4, "little", signed=True)


def test_rpdo_torque_and_consumer_heartbeat_watchdog(master, drive):
    assert sdo(master, bytes([0x2F, 0x60, 0x60, 0x00, 0x0A, 0, 0, 0]))[0] == 0x60
    # RPDO1: controlword + target torque
    for w in (bytes([0x23, 0x00, 0x14, 0x01, 0x03, 0x02, 0x00, 0x80]), bytes([0x2F, 0x00, 0x16, 0x00, 0, 0, 0, 0]),
              bytes([0x23, 0x00, 0x16, 0x01, 0x10, 0x00, 0x40, 0x60]),
              bytes([0x23, 0x00, 0x16, 0x02, 0x10, 0x00, 0x71, 0x60]),
              bytes([0x2F, 0x00, 0x16, 0x00, 0x02, 0, 0, 0]), bytes([0x23, 0x00, 0x14, 0x01, 0x03, 0x02, 0x00, 0x00]),
              bytes([0x23, 0x16, 0x10, 0x01, 0x32, 0x00, 0x7F, 0x00])):   # watch node 127, 50 ms
        assert sdo(master, w)[0] == 0x60
    send(master, 0x000, bytes([0x01, NODE_ID]))
    for cw in (0x06, 0x07, 0x0F):
        send(master, 0x203, cw.to_bytes(2, "little") + (250).to_bytes(2, "little", signed=True))
    send(master, 0x203, bytes([0x0F, 0x00]) + (250).to_bytes(2, "little", signed=True))
    sdo(master, bytes([0x40, 0x41, 0x60, 0x00, 0, 0, 0, 0]))   # round trip: RPDOs processed
    assert drive.state == State402.OPERATION_ENABLED
    assert drive.torque_command_Nm == pytest.approx(0.5)     # 250 per mille of 2 Nm
    drive.service(0.0)                                     # watchdog not armed before a heartbeat
    send(master, 0x77F, b"\x05")
    sdo(master, bytes([0x40, 0x41, 0x60, 0x00, 0, 0, 0, 0]))
    drive.service(1.0)                                     # heartbeat seen at t = 1.0
    drive.service(1.050)
    assert drive.state == State402.OPERATION_ENABLED       # 50 ms: still within the consumer time
    drain(master)
    drive.service(1.051)
    assert drive.torque_command_Nm == 0.0
    assert (EMCY, bytes([0x30, 0x81, 0x11, 0, 0, 0, 0, 0])) in drain(master)
    drive.service(1.052)
    assert drive.state == State402.FAULT


def test_injected_fault_and_reset_on_a_rising_edge_only(master, drive):
    enable_over_sdo(master)
    drive.inject_fault(0x2310)
    assert recv_id(master, EMCY) == bytes([0x10, 0x23, 0x01, 0, 0, 0, 0, 0])
    drive.service(0.0)
    assert drive.state == State402.FAULT
    SKIPPED.clear()
    sdo_write_u16(master, 0x6040, 0, 0x80)   # previous controlword 0x0F: rising edge
    assert drive.state == State402.SWITCH_ON_DISABLED
    assert (EMCY, bytes(8)) in SKIPPED + drain(master)  # error reset EMCY
    drive.inject_fault(0x4310)
    drive.service(0.0)
    sdo_write_u16(master, 0x6040, 0, 0x80)   # bit 7 held high: no edge, stays in FAULT
    assert drive.state == State402.FAULT
    sdo_write_u16(master, 0x6040, 0, 0x00)
    sdo_write_u16(master, 0x6040, 0, 0x80)
    assert drive.state == State402.SWITCH_ON_DISABLED


def test_vendor_eds_builds_a_drive_that_lists_profile_torque(master, channel):
    bus = UnixSocketBus(channel)
    sim = SimDrive(bus, NODE_ID, VENDOR_EDS, rated_torque_Nm=1.2)
    try:
        assert sdo(master, bytes([0x40, 0x02, 0x65, 0x00, 0, 0, 0, 0])) == \
            bytes([0x43, 0x02, 0x65, 0x00, 0xEF, 0x03, 0, 0])
        assert sdo(master, bytes([0x2F, 0x60, 0x60, 0x00, 0x04, 0, 0, 0]))[0] == 0x60
        assert sim.mode_display == 4
    finally:
        sim.close()
        bus.shutdown()
