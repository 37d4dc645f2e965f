"""Units read from the drive at start-up, not assumed; the simulated drive's units and CAN timing.

Against the simulated drive (drivers/sim/drive.py) and against the independent peer drive
(tests/cia402_peer, its units written from CiA 402-2 in tests/cia402_peer/units.py), both on
the Nanotec C5-E vendor EDS whose 0x60A9 says rpm and 0x60A8 tenths of a degree.
"""

from __future__ import annotations

import math
import time

import can
import pytest

from cia402_helpers import CAPSTAN_EDS, NODE_ID, VENDOR_EDS, Rig, Spy, make_motor, run_cycles
from test_cia402_peer import channel, rig as peer_rig  # noqa: F401 - fixtures: a channel; (peer, motor) on it
from capstan.drivers.can_unix import UnixSocketBus
from capstan.drivers.canopen.cia402 import State402
from capstan.drivers.canopen.drive_units import DriveUnitsError
from capstan.drivers.canopen.si_units import SiUnit
from capstan.drivers.sim.drive import SimDrive
from capstan.models.common.errors import ConfigError
from capstan.models.plant.command_path import CommandPath, CommandTiming

RPM = 2 * math.pi / 60          # rad/s of one rpm
DECI_DEG = math.pi / 1800       # rad of a tenth of a degree


@pytest.fixture
def sim(channel):
    """Factory: (rig around a SimDrive, motor driver) on one channel; closed afterwards."""
    made = []

    def _make(eds=VENDOR_EDS, sim_kwargs=None, **cfg):
        rig = Rig(channel, eds=eds, rated_torque_Nm=2.0, **(sim_kwargs or {}))
        cfg.setdefault("rated_torque_Nm", 2.0)
        motor, bus = make_motor(channel, eds=eds, **cfg)
        made.append((rig, motor, bus))
        return rig, motor

    yield _make
    for rig, motor, bus in made:
        motor.close()
        bus.shutdown()
        rig.close()


# ------------------------------------------------------------------ SI unit codes
def test_si_unit_codes_of_the_vendor_eds_defaults():
    rpm = SiUnit.decode(0x00B44700)                 # 0x60A9 of the Nanotec C5-E EDS
    assert (rpm.exponent, rpm.numerator, rpm.denominator) == (0, 0xB4, 0x47)
    assert rpm.radians / rpm.seconds == pytest.approx(RPM, rel=1e-15)
    ddeg = SiUnit.decode(0xFF410000)                # its 0x60A8: 10^-1 degree
    assert ddeg.exponent == -1 and ddeg.radians == pytest.approx(DECI_DEG, rel=1e-15)
    assert str(rpm) == "0x00B44700 (rpm)" and str(ddeg) == "0xFF410000 (0.1 deg)"
    assert SiUnit.encode(-3, 0xB4, 0x47) == 0xFDB44700 and SiUnit.decode(0xFDB44700).exponent == -3


# ------------------------------------------------------ refused: simulated drive
def test_sim_drive_in_rpm_is_refused_when_the_config_says_increments(sim):
    rig, motor = sim(velocity_units_per_rev_s=131072)
    with pytest.raises(DriveUnitsError) as err:
        motor.start()
    text = str(err.value)
    assert "motor.velocity_units_per_rev_s" in text and "0x60A9" in text and "0x00B44700 (rpm)" in text
    assert text == ("config key 'motor.velocity_units_per_rev_s': the drive reports 0x60A9 (SI unit velocity) = "
                    "0x00B44700 (rpm): 60 units of 0x606C per motor rev/s; the config states 131072 units of "
                    "0x606C per motor rev/s. Remove motor.velocity_units_per_rev_s to use the drive's value, or "
                    "correct it (docs/drive-bring-up.md, 'Units refused at start-up')")
    assert isinstance(err.value, ConfigError) and motor.network is None     # released: start may be retried


def test_sim_drive_position_unit_mismatch_names_0x60A8(sim):
    rig, motor = sim(encoder_counts_per_rev=131072)
    with pytest.raises(DriveUnitsError, match=r"0x60A8 \(SI unit position\) = 0xFF410000 \(0.1 deg\): 3600 units "
                                              r"of 0x6064 per motor rev; the config states 131072 units"):
        motor.start()


def test_sim_drive_gear_mismatch_names_0x6091(sim):
    rig, motor = sim(gear_ratio=7.0)
    with pytest.raises(DriveUnitsError, match=r"motor.gear_ratio.*0x6091 = 1:1: 1 motor revs per shaft rev; "
                                              r"the config states 7"):
        motor.start()


# ------------------------------------------------------ rpm on the wire -> rad/s
def test_sim_drive_in_rpm_gives_rad_s_with_whole_rpm_quantisation(sim):
    rig, motor = sim()                    # no unit in the config: the drive's
    rig.position_rad, rig.velocity_rad_s = 1.0, 1.0
    motor.start()
    run_cycles(motor, 20)
    rd = motor.reading
    # 1 rad/s = 9.549 rpm -> 10 rpm on the wire; 1 rad = 572.96 tenths of a degree -> 573
    assert rd.velocity_units == 10 and rd.velocity_rad_s == pytest.approx(10 * RPM, rel=1e-12)
    assert rd.position_counts == 573 and rd.position_rad == pytest.approx(573 * DECI_DEG, rel=1e-12)
    u = motor.drive_units
    assert u.velocity_units_per_rev_s == pytest.approx(60.0, rel=1e-12)
    assert u.position_units_per_rev == pytest.approx(3600.0, rel=1e-12)
    assert u.reported["0x60A9"] == "0x00B44700 (rpm)" and u.source["velocity_units_per_rev_s"] == "drive 0x60A9"


def test_sim_drive_set_to_milli_rpm_by_its_vendor_tool(sim):
    rig, motor = sim(sim_kwargs={"si_units": {0x60A9: 0xFDB44700}})
    rig.velocity_rad_s = 1.0
    motor.start()
    run_cycles(motor, 20)
    assert motor.reading.velocity_units == 9549                  # 9549.3 milli-rpm
    assert motor.reading.velocity_rad_s == pytest.approx(9549 * RPM / 1000, rel=1e-12)


def test_capstan_eds_matches_the_shipped_motor_yaml_units(sim):
    rig, motor = sim(eds=CAPSTAN_EDS, encoder_counts_per_rev=131072, velocity_units_per_rev_s=131072,
                     gear_ratio=1.0)
    rig.velocity_rad_s = 1.0
    motor.start()
    run_cycles(motor, 20)
    assert motor.reading.velocity_units == round(131072 / (2 * math.pi))
    assert motor.drive_units.reported["0x60A9"] == "0x00B50300 (inc/s)"


def test_sim_drive_refuses_a_unit_it_cannot_serve_and_serves_one_it_can(channel):
    master, bus = UnixSocketBus(channel), UnixSocketBus(channel)
    drive = SimDrive(bus, NODE_ID, VENDOR_EDS, rated_torque_Nm=2.0)
    try:
        drive.set_feedback(0.0, 1.0, 0.0)

        def sdo(request: bytes) -> bytes:
            master.send(can.Message(arbitration_id=0x600 + NODE_ID, data=request, is_extended_id=False))
            while (msg := master.recv(1.0)) is not None:
                if msg.arbitration_id == 0x580 + NODE_ID:
                    return bytes(msg.data)
            raise AssertionError("no SDO reply")

        read_606c = bytes([0x40, 0x6C, 0x60, 0x00, 0, 0, 0, 0])
        assert sdo(read_606c)[4:] == (10).to_bytes(4, "little")           # 9.55 rpm -> 10
        # metres per second: a linear unit, refused with "value range exceeded"; rpm kept
        assert sdo(bytes([0x23, 0xA9, 0x60, 0x00, 0x00, 0x03, 0x01, 0x00])) == \
            bytes([0x80, 0xA9, 0x60, 0x00, 0x30, 0x00, 0x09, 0x06])
        assert sdo(read_606c)[4:] == (10).to_bytes(4, "little")
        # tenths of an rpm: accepted, 0x606C now 95
        assert sdo(bytes([0x23, 0xA9, 0x60, 0x00, 0x00, 0x47, 0xB4, 0xFF]))[0] == 0x60
        assert sdo(read_606c)[4:] == (95).to_bytes(4, "little")
    finally:
        drive.close()
        bus.shutdown()
        master.shutdown()


# ---------------------------------------------------------- the independent peer
def test_peer_drive_in_rpm_is_refused_when_the_config_says_increments(peer_rig):
    peer, motor = peer_rig(velocity_units_per_rev_s=131072)
    with pytest.raises(DriveUnitsError, match=r"motor.velocity_units_per_rev_s.*0x60A9 \(SI unit velocity\) = "
                                              r"0x00B44700 \(rpm\): 60 units of 0x606C per motor rev/s; "
                                              r"the config states 131072"):
        motor.start()


def test_peer_drive_units_read_byte_by_byte_and_rpm_scaled(peer_rig, channel):
    spy = Spy(channel)
    try:
        peer, motor = peer_rig()
        peer.motor_speed_rev_s = 0.5                      # 30 rpm
        motor.start()
        run_cycles(motor, 20)
        replies = {bytes(r[:4]): r for r in spy.ids(0x580 + NODE_ID)}
    finally:
        spy.close()
    # expedited upload replies (CiA 301): the peer's own encoding of the vendor defaults
    assert replies[bytes([0x43, 0xA9, 0x60, 0x00])] == bytes([0x43, 0xA9, 0x60, 0x00, 0x00, 0x47, 0xB4, 0x00])
    assert replies[bytes([0x43, 0xA8, 0x60, 0x00])] == bytes([0x43, 0xA8, 0x60, 0x00, 0x00, 0x00, 0x41, 0xFF])
    assert replies[bytes([0x43, 0x8F, 0x60, 0x01])] == bytes([0x43, 0x8F, 0x60, 0x01, 0x00, 0x10, 0x00, 0x00])
    rd = motor.reading
    assert rd.velocity_units == 30 and rd.velocity_rad_s == pytest.approx(math.pi, rel=1e-12)
    # 1000 increments of a 4096-increment encoder = 87.89 degrees -> 879 tenths
    assert rd.position_counts == 879 and rd.position_rad == pytest.approx(879 * DECI_DEG, rel=1e-12)
    assert motor.state == State402.OPERATION_ENABLED


def test_peer_drive_behind_a_5_to_1_gear_reports_the_shaft(peer_rig):
    # the drive's 0x6091 = 5:1: rpm and tenths of a degree are of the shaft behind the gear
    peer, motor = peer_rig(peer_kwargs={"power_on": {(0x6091, 1): 5, (0x6091, 2): 1}})
    peer.motor_speed_rev_s = 0.5                          # the shaft turns 0.1 rev/s = 6 rpm
    motor.start()
    run_cycles(motor, 20)
    u = motor.drive_units
    assert u.gear_ratio == 5.0 and u.velocity_units_per_rev_s == pytest.approx(12.0, rel=1e-12)
    assert motor.reading.velocity_units == 6
    assert motor.reading.velocity_rad_s == pytest.approx(0.1 * 2 * math.pi, rel=1e-12)
    # 1000 of 4096 increments of the motor: 0.2441 motor rev = 0.04883 shaft rev = 175.8 -> 176 tenths
    assert motor.reading.position_counts == 176


# --------------------------------------------------------------------- CAN timing
def _run_through_drive(sim, path, targets_permille, lose_at=()):
    """Send one target per cycle through the driver and the simulated drive (capstan EDS,
    2 Nm rated); the per-mille target the drive's motor applies after each cycle's SYNC."""
    rig, motor = sim(eds=CAPSTAN_EDS, sim_kwargs={"command_path": path})
    motor.start()
    drive = rig.sim
    base = drive._sync_count
    seen = []
    for k, target in enumerate(targets_permille):
        motor.write_torque(target * 2.0 / 1000.0)
        if k in lose_at:
            path.timing = CommandTiming(0, 0.0, 1.0)          # this cycle's command is lost
        motor.send_cycle()
        deadline = time.monotonic() + 5.0          # a bound on a stalled host, not a timing claim
        while drive._sync_count < base + k + 1 and time.monotonic() < deadline:
            time.sleep(0.0005)
        assert drive._sync_count == base + k + 1, "the drive did not see this cycle's SYNC"
        if k in lose_at:
            path.timing = CommandTiming(0, 0.0, 0.0)
        seen.append(drive._applied_permille)
        motor.poll()
    return seen


def test_sim_drive_applies_the_target_two_syncs_late_and_holds_it_through_a_lost_command(sim):
    seen = _run_through_drive(sim, CommandPath(CommandTiming(0, 0.0, 0.0), 2), [50 * k for k in range(12)],
                              lose_at={8})
    # cycle k's target reaches the motor at cycle k + 2; cycle 8's was lost: the motor keeps
    # cycle 7's target until cycle 9's arrives
    assert seen[2:] == [0, 50, 100, 150, 200, 250, 300, 350, 350, 450]


def test_sim_drive_command_delay_one_to_three_cycles_in_order(sim):
    n = 300
    path = CommandPath(CommandTiming(1, 0.5, 0.02), 2, seed=5)   # half the commands jittered, 2 % lost
    seen = _run_through_drive(sim, path, list(range(1, n + 1)))
    first_seen = {}
    for cycle, target in enumerate(seen):
        if target and target not in first_seen:
            first_seen[target] = cycle
    delays = {first_seen[t] - (t - 1) for t in first_seen}         # target t was sent in cycle t - 1
    assert delays == {1, 2, 3}                                      # nominal 2, jitter +-1, none other
    assert all(b >= a for a, b in zip(seen, seen[1:]))              # never an older target after a newer
    assert path.lost > 0 and len(first_seen) < n - 3                # lost ones never reach the motor


# ------------------------------------------------------------ motor.units: write
def test_units_write_sets_the_peer_to_milli_rpm_before_the_check(peer_rig):
    peer, motor = peer_rig(units="write", velocity_units_per_rev_s=60000, encoder_counts_per_rev=3600)
    peer.motor_speed_rev_s = 0.5
    motor.start()
    run_cycles(motor, 20)
    assert peer.value(0x60A9) == 0xFDB44700 and peer.value(0x60A8) == 0xFF410000
    assert motor.reading.velocity_units == 30000
    assert motor.reading.velocity_rad_s == pytest.approx(math.pi, rel=1e-12)


def test_units_write_refuses_a_value_no_unit_code_makes(peer_rig):
    peer, motor = peer_rig(units="write", velocity_units_per_rev_s=131072)    # the peer's encoder: 4096
    with pytest.raises(DriveUnitsError, match=r"motor.velocity_units_per_rev_s.*no 0x60A9 unit code gives "
                                              r"131072 units per motor rev/s"):
        motor.start()
    assert peer.value(0x60A9) == 0x00B44700                                 # nothing written


def test_units_write_sets_the_sim_drive_to_increments_per_second(sim):
    rig, motor = sim(units="write", velocity_units_per_rev_s=131072)
    rig.velocity_rad_s = 1.0
    motor.start()
    run_cycles(motor, 20)
    assert motor.drive_units.reported["0x60A9"] == "0x00B50300 (inc/s)"
    assert motor.reading.velocity_units == round(131072 / (2 * math.pi))
