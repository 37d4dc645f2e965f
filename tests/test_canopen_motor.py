"""The CANopen CiA 402 motor driver against the simulated drive, down to the CAN frames."""

from __future__ import annotations

import math
import time

import can
import pytest

from cia402_helpers import CAPSTAN_EDS, NODE_ID, ROOT, VENDOR_EDS, Rig, Spy, make_motor, run_cycles
from capstan.drivers.canopen.motor import CanopenMotor, ObjectMissingError
from capstan.drivers.canopen.cia402 import State402
from capstan.drivers.canopen.config import MotorConfig
from capstan.models.common.errors import (ConfigError, DriveFaultError, DriverError, HeartbeatLostError)

SDO_RX = 0x600 + NODE_ID


@pytest.fixture
def channel(tmp_path):
    return str(tmp_path / "can0")


@pytest.fixture
def setup(channel):
    """Factory: (rig, motor, spy) on one channel; everything closed afterwards."""
    made = []

    def _make(eds=CAPSTAN_EDS, rated_torque_Nm=2.0, spy=False, motor_rated_torque_Nm="same",
              sim_kwargs=None, **cfg):
        """rated_torque_Nm: the simulated drive's; motor_rated_torque_Nm: the configuration's."""
        rig = Rig(channel, eds=eds, rated_torque_Nm=rated_torque_Nm, **(sim_kwargs or {}))
        sp = Spy(channel) if spy else None
        cfg["rated_torque_Nm"] = rated_torque_Nm if motor_rated_torque_Nm == "same" else motor_rated_torque_Nm
        motor, bus = make_motor(channel, eds=eds, **cfg)
        made.append((rig, motor, bus, sp))
        return rig, motor, sp

    yield _make
    for rig, motor, bus, sp in made:
        motor.close()
        bus.shutdown()
        if sp is not None:
            sp.close()
        rig.close()


def sdo_download(index, sub, value, size):
    cmd = {1: 0x2F, 2: 0x2B, 4: 0x23}[size]
    return bytes([cmd, index & 0xFF, index >> 8, sub]) + value.to_bytes(size, "little") + bytes(4 - size)


def sdo_upload(index, sub):
    return bytes([0x40, index & 0xFF, index >> 8, sub, 0, 0, 0, 0])


def test_start_up_sdo_conversation_exact_bytes(setup):
    rig, motor, spy = setup(rated_torque_Nm=2.0, spy=True, motor_rated_torque_Nm=None,
                            drive_heartbeat_period_s=0.01, consumer_timeout_s=0.05)
    motor.start()
    time.sleep(0.02)
    d = sdo_download
    n = NODE_ID
    expected = [
        sdo_upload(0x1000, 0),                        # device type: the drive has booted
        sdo_upload(0x6041, 0),                        # statusword: not in FAULT
        sdo_upload(0x6502, 0),                        # supported modes
        # units: encoder resolution, gear ratio, SI unit position/velocity, rated torque [mNm]
        sdo_upload(0x608F, 1), sdo_upload(0x608F, 2), sdo_upload(0x6091, 1), sdo_upload(0x6091, 2),
        sdo_upload(0x60A8, 0), sdo_upload(0x60A9, 0),
        sdo_upload(0x6076, 0),
        sdo_upload(0x1014, 0),                        # EMCY COB-ID
        # RPDO1: disable, SYNC type 1, mapping controlword + target torque, enable
        sdo_upload(0x1400, 1), d(0x1400, 1, 0x80000200 + n, 4), d(0x1400, 2, 1, 1),
        d(0x1600, 0, 0, 1), d(0x1600, 1, 0x60400010, 4), d(0x1600, 2, 0x60710010, 4), d(0x1600, 0, 2, 1),
        d(0x1400, 1, 0x200 + n, 4),
        # TPDO1: statusword, mode display, position
        sdo_upload(0x1800, 1), d(0x1800, 1, 0x80000180 + n, 4), d(0x1800, 2, 1, 1),
        d(0x1A00, 0, 0, 1), d(0x1A00, 1, 0x60410010, 4), d(0x1A00, 2, 0x60610008, 4),
        d(0x1A00, 3, 0x60640020, 4), d(0x1A00, 0, 3, 1), d(0x1800, 3, 0, 2), d(0x1800, 5, 0, 2),
        d(0x1800, 1, 0x180 + n, 4),
        # TPDO2: velocity, torque
        sdo_upload(0x1801, 1), d(0x1801, 1, 0x80000280 + n, 4), d(0x1801, 2, 1, 1),
        d(0x1A01, 0, 0, 1), d(0x1A01, 1, 0x606C0020, 4), d(0x1A01, 2, 0x60770010, 4), d(0x1A01, 0, 2, 1),
        d(0x1801, 3, 0, 2), d(0x1801, 5, 0, 2), d(0x1801, 1, 0x280 + n, 4),
        # other PDOs switched off
        sdo_upload(0x1401, 1), d(0x1401, 1, 0x80000300 + n, 4),
        sdo_upload(0x1402, 1), d(0x1402, 1, 0x80000400 + n, 4),
        sdo_upload(0x1403, 1), d(0x1403, 1, 0x80000500 + n, 4),
        sdo_upload(0x1802, 1), d(0x1802, 1, 0x80000380 + n, 4),
        sdo_upload(0x1803, 1), d(0x1803, 1, 0x80000480 + n, 4),
        d(0x60C2, 1, 1, 1), d(0x60C2, 2, 0xFD, 1),    # interpolation period 1 x 10^-3 s
        d(0x1017, 0, 10, 2),                          # drive heartbeat every 10 ms
        # safety objects, each read back: abort connection option 1 (fault), communication
        # error -> pre-operational, quick stop option 2, shutdown option 0, max torque 30 Nm
        d(0x6007, 0, 1, 2), sdo_upload(0x6007, 0), d(0x1029, 1, 0, 1), sdo_upload(0x1029, 1),
        d(0x605A, 0, 2, 2), sdo_upload(0x605A, 0), d(0x605B, 0, 0, 2), sdo_upload(0x605B, 0),
        d(0x6072, 0, 15000, 2), sdo_upload(0x6072, 0),
        d(0x6060, 0, 10, 1), sdo_upload(0x6061, 0),   # CST, verified on 0x6061
        d(0x1016, 1, (0x7F << 16) | 50, 4),           # drive watches node 127 with 50 ms
    ]
    requests = spy.ids(SDO_RX)
    assert requests[:len(expected)] == expected
    # then the transitions to OPERATION ENABLED, each planned on the statusword read now,
    # and the enabled state verified on 0x6041 and 0x6061: uploads only
    rest = requests[len(expected):]
    assert sdo_upload(0x6041, 0) in rest and rest[-1] == sdo_upload(0x6041, 0)
    assert set(rest) == {sdo_upload(0x6041, 0), sdo_upload(0x6061, 0)}
    responses = spy.ids(0x580 + NODE_ID)
    assert len(responses) == len(requests) and all(r[0] != 0x80 for r in responses)  # no abort
    # the unit reads, byte for byte: 2^17 increments per 1 motor revolution, gear 1:1,
    # position in increments (0x00B50000), velocity in increments per second (0x00B50300)
    assert responses[3:9] == [bytes([0x43, 0x8F, 0x60, 0x01, 0x00, 0x00, 0x02, 0x00]),
                              bytes([0x43, 0x8F, 0x60, 0x02, 0x01, 0x00, 0x00, 0x00]),
                              bytes([0x43, 0x91, 0x60, 0x01, 0x01, 0x00, 0x00, 0x00]),
                              bytes([0x43, 0x91, 0x60, 0x02, 0x01, 0x00, 0x00, 0x00]),
                              bytes([0x43, 0xA8, 0x60, 0x00, 0x00, 0x00, 0xB5, 0x00]),
                              bytes([0x43, 0xA9, 0x60, 0x00, 0x00, 0x03, 0xB5, 0x00])]
    assert responses[9] == bytes([0x43, 0x76, 0x60, 0x00, 0xD0, 0x07, 0x00, 0x00])      # 2000 mNm
    assert spy.ids(0x000) == [bytes([0x80, n]), bytes([0x01, n])]   # pre-operational, then start
    assert motor.rated_torque_Nm == 2.0
    assert motor.state == State402.OPERATION_ENABLED


def test_cycle_frames_and_scaled_feedback(setup):
    rig, motor, spy = setup(spy=True)
    motor.start()
    t_start = time.monotonic()
    run_cycles(motor, 30, torque_Nm=0.5)
    time.sleep(0.02)
    reading = motor.poll() or motor.reading
    ours = [(i, d) for t, i, d in spy.frames if t > t_start and i in (0x200 + NODE_ID, 0x80)]
    assert ours[:4] == [(0x203, bytes([0x0F, 0x00, 0xFA, 0x00])), (0x080, b""),   # 250 per mille of 2 Nm
                        (0x203, bytes([0x0F, 0x00, 0xFA, 0x00])), (0x080, b"")]
    assert all(ours[k][0] == (0x203, 0x080)[k % 2] for k in range(len(ours)))      # RPDO, then SYNC
    count_rad = 2 * math.pi / (1 << 17)
    assert abs(reading.position_rad - 1.0) <= count_rad
    assert abs(reading.velocity_rad_s - (-2.0)) <= count_rad
    assert reading.torque_Nm == pytest.approx(0.5)     # the stub plant applies the command
    assert rig.sim.torque_command_Nm == pytest.approx(0.5)
    assert reading.mode == 10 and reading.statusword & 0x6F == 0x27


def test_daemon_heartbeat_is_produced_from_the_cycle(setup):
    rig, motor, spy = setup(spy=True)
    motor.start()
    time.sleep(0.03)
    n_before = len(spy.ids(0x77F))
    stamps = []
    for _ in range(150):
        stamps.append(time.monotonic())
        run_cycles(motor, 1)
    time.sleep(0.03)
    frames = spy.ids(0x77F)
    assert all(d == b"\x05" for d in frames)                # NMT state OPERATIONAL
    n_hb = len(frames) - n_before
    run_s = stamps[-1] - stamps[0]
    longest_cycle_s = max(b - a for a, b in zip(stamps, stamps[1:]))
    # sent on the first cycle at least 10 ms after the previous one
    assert run_s / (0.010 + longest_cycle_s) - 1 <= n_hb <= run_s / 0.010 + 1


def test_vendor_eds_reaches_operation_enabled_in_cst(setup):
    rig, motor, _ = setup(eds=VENDOR_EDS, rated_torque_Nm=1.2)
    motor.start()
    assert motor.state == State402.OPERATION_ENABLED
    assert rig.sim.mode_display == 10 and motor.reading.mode == 10
    run_cycles(motor, 20, torque_Nm=0.6)
    assert rig.sim.torque_command_Nm == pytest.approx(0.6)


def test_vendor_eds_lacks_0x6076_so_the_rated_torque_must_be_configured(setup):
    rig, motor, _ = setup(eds=VENDOR_EDS, rated_torque_Nm=1.2, motor_rated_torque_Nm=None)
    with pytest.raises(ConfigError) as err:
        motor.start()
    assert err.value.key == "motor.rated_torque_Nm" and "0x6076" in err.value.reason


def test_profile_torque_where_0x6502_lists_it(setup):
    rig, motor, _ = setup(eds=VENDOR_EDS, rated_torque_Nm=1.2, mode="profile_torque")
    motor.start()
    assert motor.reading.mode == 4 and rig.sim.mode_display == 4


def test_cst_only_drive_refuses_profile_torque(setup):
    rig, motor, spy = setup(mode="profile_torque", spy=True)
    with pytest.raises(DriverError, match="0x6502"):
        motor.start()
    time.sleep(0.02)
    assert sdo_download(0x6060, 0, 4, 1) not in spy.ids(SDO_RX)   # never even tried
    assert rig.sim.state == State402.SWITCH_ON_DISABLED


@pytest.mark.parametrize("mode, ok", [("cst", True), ("profile_torque", False)])
def test_vendor_drive_listing_only_cst(setup, mode, ok):
    rig, motor, _ = setup(eds=VENDOR_EDS, rated_torque_Nm=1.2, mode=mode,
                          sim_kwargs={"supported_modes": 1 << 9})   # 0x6502 = CST only
    if ok:
        motor.start()
        assert motor.reading.mode == 10 and motor.state == State402.OPERATION_ENABLED
    else:
        with pytest.raises(DriverError, match=r"0x6502 = 0x00000200 lacks bit 3"):
            motor.start()


def test_missing_required_object_is_a_clear_error(setup, tmp_path):
    text = open(CAPSTAN_EDS).read()
    start = text.index("[6071]")
    end = text.index("[6072]")
    eds = tmp_path / "no6071.eds"
    eds.write_text(text[:start] + text[end:])
    rig, motor, _ = setup()
    motor.config = MotorConfig.from_mapping({"node_id": NODE_ID, "eds": str(eds)})
    with pytest.raises(ObjectMissingError, match=r"0x6071 \(target torque\)"):
        motor.start()


def test_rated_torque_contradicting_the_drive_is_refused(setup):
    rig, motor, _ = setup(rated_torque_Nm=2.0, motor_rated_torque_Nm=3.0)
    with pytest.raises(ConfigError, match="0x6076 = 2000 mNm: 2 Nm; the config states 3 Nm"):
        motor.start()


def test_emcy_fault_is_latched_and_reset_with_a_rising_edge(setup):
    rig, motor, spy = setup(spy=True)
    motor.start()
    run_cycles(motor, 5, torque_Nm=0.3)
    rig.sim.inject_fault(0x4310)
    with pytest.raises(DriveFaultError, match="excess temperature, drive"):
        run_cycles(motor, 50)
    with pytest.raises(DriveFaultError):
        motor.poll()                                   # latched
    assert rig.sim.torque_command_Nm == 0.0
    t_reset = time.monotonic()
    motor.fault_reset()
    assert motor.state == State402.SWITCH_ON_DISABLED
    time.sleep(0.02)
    cws = [int.from_bytes(d[:2], "little") for t, i, d in spy.frames if i == 0x203 and t > t_reset]
    k = cws.index(0x0080)
    assert cws[k - 1] & 0x80 == 0                      # bit 7 low before: a real rising edge
    motor.enable()
    run_cycles(motor, 10, torque_Nm=0.3)
    assert rig.sim.torque_command_Nm == pytest.approx(0.3)


def test_drive_heartbeat_loss_is_detected_within_3_periods(setup):
    rig, motor, _ = setup(drive_heartbeat_period_s=0.01)
    motor.start()
    run_cycles(motor, 20)
    rig.servicing = False                               # drive stops producing heartbeats
    with pytest.raises(HeartbeatLostError, match="3 periods"):
        for _ in range(200):
            run_cycles(motor, 1)
    # never before 3 periods (3 x 10 ms) of silence: the rule, which load cannot break; the upper
    # bound is liveness only (the latency's distribution: tests/bench_latency.py)
    latency_s = time.monotonic() - motor._hb_last_s
    assert 0.030 < latency_s < 1.0


def test_daemon_heartbeat_stop_faults_the_drive_and_zeroes_torque(setup):
    rig, motor, spy = setup(spy=True, consumer_timeout_s=0.05)
    motor.start()
    run_cycles(motor, 30, torque_Nm=0.8)
    assert rig.sim.torque_command_Nm == pytest.approx(0.8)
    last_hb_sent_s = motor._hb_next_s - motor.config.heartbeat_period_s   # the daemon stops here
    deadline = time.monotonic() + 0.5
    while rig.sim.state != State402.FAULT and time.monotonic() < deadline:
        time.sleep(0.0005)
    t_fault = time.monotonic()
    assert rig.sim.state == State402.FAULT and rig.sim.torque_command_Nm == 0.0
    # not before the 50 ms consumer time (the rule; the heartbeat left at or after last_hb_sent_s); that
    # it came at all is the 0.5 s deadline above (the latency's distribution: tests/bench_latency.py)
    assert 0.050 < t_fault - last_hb_sent_s
    time.sleep(0.02)
    assert spy.ids(0x80 + NODE_ID)[0] == bytes([0x30, 0x81, 0x11, 0, 0, 0, 0, 0])
    with pytest.raises(DriveFaultError, match="heartbeat"):
        motor.poll()


def test_tpdo_never_missed_over_many_cycles(setup):
    rig, motor, _ = setup()
    motor.start()
    time.sleep(0.03)   # TPDOs of the last start-up SYNC may still be in flight
    motor.poll()
    before = (motor.syncs_sent, motor.tpdo1_received, motor.tpdo2_received)
    assert before[0] == before[1] == before[2]
    run_cycles(motor, 2000, torque_Nm=0.1, period_s=0.0005)
    deadline = time.monotonic() + 2.0          # let late frames arrive (shared, loaded machine)
    while motor.tpdo2_received - before[2] < 2000 and time.monotonic() < deadline:
        time.sleep(0.005)
        motor.poll()
    sent = motor.syncs_sent - before[0]
    assert sent == 2000 and motor._bus.tx_dropped == 0 and rig.bus.tx_dropped == 0
    assert motor.tpdo1_received - before[1] == sent
    assert motor.tpdo2_received - before[2] == sent


def test_dead_receive_thread_during_start_up_is_a_fault(setup):
    rig, motor, _ = setup()
    motor.DIRECT_READ = False            # keep canopen's notifier thread after start-up
    motor.start()
    motor.network.notifier.exception = OSError("bus gone")
    with pytest.raises(DriverError, match="receive thread died"):
        motor.poll()


def test_after_start_up_poll_reads_the_bus_itself(setup, monkeypatch):
    rig, motor, _ = setup()
    motor.start()
    assert not any(t.is_alive() for t in motor._rx_threads)   # no receive thread left
    run_cycles(motor, 5)

    def broken(timeout=None):
        raise can.CanOperationError("interface down")
    monkeypatch.setattr(motor._bus, "recv", broken)
    with pytest.raises(DriverError, match="CAN receive failed: interface down"):
        motor.poll()


def test_quick_stop_and_disable(setup):
    rig, motor, _ = setup()
    motor.start()
    run_cycles(motor, 5, torque_Nm=0.5)
    motor.quick_stop()
    assert rig.sim.torque_command_Nm == 0.0
    assert motor.state in (State402.QUICK_STOP_ACTIVE, State402.SWITCH_ON_DISABLED)
    motor.enable()
    assert motor.state == State402.OPERATION_ENABLED
    motor.disable()
    assert motor.state == State402.READY_TO_SWITCH_ON and rig.sim.state == State402.READY_TO_SWITCH_ON


@pytest.mark.parametrize("cfg, key", [
    ({"node_id": 0}, "motor.node_id"),
    ({"mode": "torque"}, "motor.mode"),
    ({"eds": "/nonexistent.eds"}, "motor.eds"),
    ({"cutoff": 1}, "motor.cutoff"),
    ({"heartbeat_period_s": 0.2, "consumer_timeout_s": 0.1}, "motor.consumer_timeout_s"),
    ({"node_id": 5, "master_node_id": 5}, "motor.master_node_id"),
    ({"abort_connection_option": 0}, "motor.abort_connection_option"),
    ({"comm_error_behaviour": 3}, "motor.comm_error_behaviour"),
    ({"quick_stop_option": 9}, "motor.quick_stop_option"),
    ({"shutdown_option": True}, "motor.shutdown_option"),
    ({"fault_reset_at_start": "yes"}, "motor.fault_reset_at_start"),
    ({"boot_timeout_s": 0.0}, "motor.boot_timeout_s"),
])
def test_bad_configuration_names_the_key(cfg, key):
    with pytest.raises(ConfigError) as err:
        MotorConfig.from_mapping(cfg)
    assert err.value.key == key


def test_shipped_example_config_builds_the_motor_through_the_registry():
    from capstan.drivers import registry
    from capstan.models.common.config_tools import load_yaml
    cfg = load_yaml(ROOT / "config" / "motor.yaml")["motor"]
    motor = registry.create("motor", cfg)
    assert isinstance(motor, CanopenMotor)
    assert motor.config.interface == "socketcan" and motor.config.mode == "cst"
    assert motor.config.eds.endswith("capstan_drive.eds")


def test_simulated_drive_caps_at_0x6072_and_reports_bit_11(setup):
    rig, motor, _ = setup(max_torque_Nm=0.6)
    motor.start()
    assert rig.sim._value(0x6072, 0) == 300                       # 0.6 Nm of 2 Nm, read back
    run_cycles(motor, 20, 0.6)
    assert rig.sim.torque_command_Nm == pytest.approx(0.6) and motor.internal_limit_cycles == 0
    with rig.sim._lock:
        rig.sim._store(0x6072, 0, 100)                            # the drive derates itself
    run_cycles(motor, 30, 0.6)
    assert rig.sim.torque_command_Nm == pytest.approx(0.2) and motor.internal_limit_cycles >= 20
