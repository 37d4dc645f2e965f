"""The :class:`~capstan.drivers.interfaces.Motor` role on a CANopen CiA 402 drive.

Start-up (blocking, SDO only, through canopen's ``RemoteNode``): required objects
checked in the EDS, the drive waited for (boot-up message or SDO polled with back-off
up to ``boot_timeout_s``, :mod:`~capstan.drivers.canopen.bringup`), NMT pre-operational,
a FAULT the previous daemon left (heartbeat loss 0x8130) reset and named, any other
fault refused unless ``fault_reset_at_start``; 0x6502 checked for the configured mode,
units read from the drive (0x608F/0x6091/0x6092/0x60A8/0x60A9/0x6076, checked against the
configuration, :mod:`~capstan.drivers.canopen.drive_units`), PDO mapping (RPDO1: controlword 0x6040 +
target torque 0x6071; TPDO1: statusword 0x6041 + mode display 0x6061 + position
0x6064; TPDO2: velocity 0x606C + torque 0x6077; all SYNC type 1, other PDOs
disabled), interpolation period 0x60C2, drive heartbeat 0x1017, drive consumer
heartbeat 0x1016 on the daemon, safety objects 0x6007/0x1029/0x605A/0x605B/0x6072
written and read back, mode 0x6060 verified on 0x6061, NMT start, then the DS402
transitions of :mod:`capstan.drivers.canopen.cia402` towards OPERATION ENABLED, each
within its timeout, with controlword and SYNC sent cycle by cycle. Every transition
starts from the statusword read over SDO (never a stale TPDO: a drive that left NMT
OPERATIONAL sends none), and :meth:`CanopenMotor.enable` succeeds only when a fresh
0x6041/0x6061 and the drive's heartbeat say OPERATION ENABLED, the mode, NMT OPERATIONAL.
A failed :meth:`~CanopenMotor.start` releases what it set up, so it can be called again.

Shutdown (:meth:`~CanopenMotor.close`, after the daemon's ramp): disable, disarm the
drive's consumer heartbeat 0x1016, NMT pre-operational, and only then the daemon's
heartbeat stops — the drive is left restartable, not faulted. A drive that is gone (no
heartbeat for 3 periods) is given up within that time, as :class:`DeviceLostError`.

Per cycle (never blocks, no SDO): :meth:`CanopenMotor.write_torque` stages the
torque, :meth:`~CanopenMotor.send_cycle` sends RPDO1 then SYNC (and the daemon
heartbeat when due) with ``bus.send``, :meth:`~CanopenMotor.poll` takes every frame
received since the last poll, in order (no TPDO overwritten or missed) and checks the
drive heartbeat (lost after 3 periods), EMCY and the statusword. A fault is latched
and raised by every poll until :meth:`fault_reset`.

Reception: during start-up canopen's notifier thread feeds SDO and a queue of our
frames (supervised: a dead thread is a fault). Once the drive is enabled the thread is
stopped and :meth:`poll` reads the bus itself with non-blocking ``recv(0)``
(``DIRECT_READ``): no thread that can die silently or be starved of the GIL by a
busy-waiting loop. SDO after that (statusword reads, disarming 0x1016) is sent and
answered on the same direct path, cycle by cycle (:mod:`~capstan.drivers.canopen.sdo_direct`).
Statusword bit 11 (internal limit active: the drive capped the command) is counted in
:attr:`CanopenMotor.internal_limit_cycles` and logged as a warning.
"""

from __future__ import annotations

import logging
import math
import struct
import threading
import time
from collections import deque
from typing import Any, Mapping

import can
import canopen

from capstan.drivers.canopen.bringup import recover_fault_at_start, wait_for_boot
from capstan.drivers.canopen.drive_setup import ObjectMissingError, check_required_objects, configure_drive
from capstan.drivers.canopen.drive_units import DriveUnits
from capstan.drivers.canopen.ds402_control import Ds402Control
from capstan.drivers.canopen.cia402 import OpMode, State402, decode_statusword, describe_statusword
from capstan.drivers.canopen.emcy import EmcyFault, decode_emcy
from capstan.drivers.interfaces import MotorReading
from capstan.drivers.canopen.config import MotorConfig
from capstan.models.common.wire_units import NS_TO_S, Derivation, motor_torque_ops, scale_ops, seconds_from_ns
from capstan.models.common.errors import DeviceTimeoutError, DriveFaultError, DriverError, HeartbeatLostError

__all__ = ["CanopenMotor", "ObjectMissingError"]

logger = logging.getLogger(__name__)


_RPDO1 = struct.Struct("<Hh")
_TPDO1 = struct.Struct("<Hbi")
_TPDO2 = struct.Struct("<ih")
_NMT_OPERATIONAL = 0x05
_MODE = {"cst": OpMode.CYCLIC_SYNC_TORQUE, "profile_torque": OpMode.PROFILE_TORQUE}


class CanopenMotor(Ds402Control):
    """CiA 402 drive over python-can + canopen; see the module docstring.

    :param config: validated motor configuration.
    :param bus: an open python-can bus to use (default: opened from the configuration).
    """

    #: default timeout of each DS402 transition number [s]
    TRANSITION_TIMEOUT_S: dict[int, float] = {1: 2.0, 14: 1.0, 2: 0.5, 3: 0.5, 4: 1.0, 5: 0.5, 6: 0.5, 7: 0.5,
                                              8: 0.5, 9: 0.5, 10: 0.5, 11: 0.5, 12: 2.0,
                                              15: 1.0, 16: 0.5}
    SDO_TIMEOUT_S = 0.5             #: SDO response timeout [s]
    MODE_TIMEOUT_S = 0.5            #: time for 0x6061 to show the written mode [s]
    FIRST_TPDO_TIMEOUT_S = 1.0      #: time for the first TPDO and heartbeat after NMT start [s]
    HEARTBEAT_LOSS_PERIODS = 3      #: drive heartbeat periods without a frame -> lost
    NOTIFIER_CYCLE_S = 0.05         #: receive thread wake-up period (shutdown latency) [s]
    #: after start-up, poll() reads the bus itself instead of canopen's notifier thread
    #: (no thread to die or to starve under the GIL; TPDOs are taken in order at poll time)
    DIRECT_READ = True

    def __init__(self, config: MotorConfig, bus: can.BusABC | None = None) -> None:
        self.config = config
        self._own_bus = bus is None
        self._bus = bus
        self.network: canopen.Network | None = None
        self.node: canopen.RemoteNode | None = None
        #: feedback scales: the configuration's until :meth:`start` reads the drive's (None if it states none)
        self.drive_units: DriveUnits | None = None
        self._pos_scale = self._vel_scale = math.nan
        self.rated_torque_Nm = config.rated_torque_Nm or 0.0
        self._use_units(DriveUnits.from_config(config))
        self.mode = _MODE[config.mode]
        self.state = State402.UNKNOWN
        self.last_emcy: EmcyFault | None = None
        self.reading = MotorReading()
        self.syncs_sent = 0
        self.tpdo1_received = 0
        self.tpdo2_received = 0
        self._rx: deque[tuple[int, bytes, float]] = deque()
        self._rx_threads: list[threading.Thread] = []
        self._direct = False
        self._handover = False
        self._fault: DriverError | None = None
        self._controlword = 0
        self._torque_permille = 0
        self._expect_enabled = False
        self._hb_last_s: float | None = None
        self._hb_next_s = 0.0
        #: CAN-IDs of TPDO1, TPDO2, EMCY (-1: none), drive heartbeat, SDO server reply
        self._cobs: tuple[int, int, int, int, int] = (0, 0, -1, 0, 0)
        self._sdo_reply: bytes | None = None
        self._new_tpdo = False
        #: NMT state in the drive's last heartbeat (None before the first)
        self.nmt_state: int | None = None
        #: error code of the FAULT reset at the last start-up (0x8130 after a killed daemon), or None
        self.recovered_fault: int | None = None
        #: safety objects as read back at start-up (``{"0x6072": 300, ...}``)
        self.safety_objects: dict[str, int] = {}
        #: TPDOs with statusword bit 11 (internal limit active: the drive capped the command)
        self.internal_limit_cycles = 0
        self._limit_active = False
        self._limit_logged_s = -math.inf
        self._rpdo_msg = can.Message(arbitration_id=0x200 + config.node_id, data=bytearray(4),
                                     is_extended_id=False)
        self._sync_msg = can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)
        self._hb_msg = can.Message(arbitration_id=0x700 + config.master_node_id,
                                   data=bytes([_NMT_OPERATIONAL]), is_extended_id=False)

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any], prefix: str = "motor") -> "CanopenMotor":
        """Build from a ``motor:`` mapping (used by :mod:`capstan.drivers.registry`).

        :raises ConfigError: naming the offending key.
        """
        return cls(MotorConfig.from_mapping(cfg, prefix))

    # ================================================================ start-up
    def start(self) -> None:
        """Wait for the drive, configure it over SDO, start NMT and bring it to OPERATION ENABLED.

        After a failure everything set up is released: ``start()`` may be called again.

        :raises ObjectMissingError: if the EDS lacks a required object.
        :raises ConfigError: if the rated torque is unknown or contradicts 0x6076, or 0x60C2/0x6072
            cannot hold the configured period/limit.
        :raises DeviceTimeoutError: if the drive does not boot within ``boot_timeout_s``.
        :raises DriveFaultError: if the drive is in a FAULT it did not get from the daemon's death
            (code and text named) and ``fault_reset_at_start`` is not set.
        :raises DriverError: (or a subclass) if a step fails, is refused (object named) or times out.
        """
        cfg = self.config
        if self.network is not None:
            raise DriverError(f"drive {cfg.node_id}: start() while started; close() first")
        od = canopen.import_od(cfg.eds, cfg.node_id)
        check_required_objects(od, cfg.eds)
        self._reset_session()
        if self._bus is None:
            try:
                self._bus = can.Bus(interface=cfg.interface, channel=cfg.channel, bitrate=cfg.bitrate)
            except (can.CanError, OSError, ValueError) as exc:
                raise DriverError(f"cannot open CAN interface {cfg.interface!r} channel "
                                  f"{cfg.channel!r}: {exc}") from exc
        try:
            self._start_on_bus(od)
        except BaseException:
            self._release()
            raise

    def _reset_session(self) -> None:
        self.state = State402.UNKNOWN
        self.reading = MotorReading()
        self.tpdo1_received = self.tpdo2_received = 0
        self._rx.clear()
        self._direct = self._handover = self._expect_enabled = False
        self._fault = None
        self._controlword = self._torque_permille = 0
        self._hb_last_s = None
        self.nmt_state = None
        self.recovered_fault = None

    def _start_on_bus(self, od: canopen.ObjectDictionary) -> None:
        cfg, nid = self.config, self.config.node_id
        self.network = canopen.Network(self._bus)
        self.network.NOTIFIER_CYCLE = self.NOTIFIER_CYCLE_S
        self.network.connect()
        # python-can 4.x keeps its reader threads in Notifier._readers; supervised by _drain()
        self._rx_threads = [t for t in getattr(self.network.notifier, "_readers", [])
                            if isinstance(t, threading.Thread)]
        self.node = self.network.add_node(nid, od)
        self.node.sdo.RESPONSE_TIMEOUT = self.SDO_TIMEOUT_S
        wait_for_boot(self.network, self.node, cfg.boot_timeout_s)
        self.node.nmt.send_command(0x80)  # enter PRE-OPERATIONAL
        self.recovered_fault = recover_fault_at_start(self.node, cfg)
        done = configure_drive(self.node, cfg, self.mode, self.MODE_TIMEOUT_S)
        self._use_units(done.units)
        self.safety_objects = done.safety
        self._rpdo_msg.arbitration_id = done.rpdo_cob
        self._cobs = (done.tpdo1_cob, done.tpdo2_cob, done.emcy_cob or -1, 0x700 + nid, 0x580 + nid)
        for cob in self._cobs[:4]:
            if cob >= 0:
                self.network.subscribe(cob, self._on_frame)
        self.node.nmt.send_command(0x01)  # NMT start
        self._wait_first_feedback()
        self.enable()
        if self.DIRECT_READ:
            self._stop_notifier()

    def _use_units(self, units: DriveUnits | None) -> None:
        self.drive_units = units
        if units is not None:
            self.rated_torque_Nm = units.rated_torque_Nm
            self._pos_scale, self._vel_scale = units.position_rad_per_unit, units.velocity_rad_s_per_unit

    def _release(self) -> None:
        """Undo start-up: unsubscribe, stop the receive thread, forget the node (bus kept or shut)."""
        net, self.network = self.network, None
        self._direct = False
        if net is None:
            return
        for cob in self._cobs[:4]:
            if self._on_frame in net.subscribers.get(cob, ()):
                net.unsubscribe(cob, self._on_frame)
        try:
            if net.notifier is not None:
                net.notifier.stop(net.NOTIFIER_SHUTDOWN_TIMEOUT)
            if self.config.node_id in net:
                del net[self.config.node_id]
        except Exception as exc:  # a dead receive thread re-raises its error here
            logger.warning("drive %d: release: %s", self.config.node_id, exc)
        if self._own_bus and self._bus is not None:
            self._bus.shutdown()
            self._bus = None

    def _stop_notifier(self) -> None:
        """Hand reception over from canopen's notifier thread to :meth:`poll`."""
        notifier = self.network.notifier
        if notifier is None:
            return
        self._handover = True
        notifier.stop(timeout=0)          # ask the reader thread to end; keep cycling meanwhile
        deadline = time.monotonic() + 4 * self.NOTIFIER_CYCLE_S + 0.5
        while any(t.is_alive() for t in self._rx_threads):
            if time.monotonic() > deadline:
                raise DriverError("CAN receive thread does not stop")
            self._step()
        self._direct = True

    def _wait_first_feedback(self) -> None:
        deadline = time.monotonic() + self.FIRST_TPDO_TIMEOUT_S
        while self.tpdo1_received == 0 or self._hb_last_s is None:
            if time.monotonic() > deadline:
                what = "TPDO1" if self.tpdo1_received == 0 else "heartbeat"
                raise DeviceTimeoutError(f"drive {self.config.node_id}: no {what} within "
                                         f"{self.FIRST_TPDO_TIMEOUT_S} s of NMT start")
            self._step()

    # ================================================================ per cycle
    def write_torque(self, torque_Nm: float) -> None:
        """Stage the target torque [Nm] for the next cycle (clamped to max_torque_Nm; NaN -> 0).

        :raises DriverError: before :meth:`start` (the rated torque is not known yet).
        """
        if not self.rated_torque_Nm > 0:
            raise DriverError("motor not started: rated torque unknown")
        lim = self.config.max_torque_Nm
        tau = min(lim, max(-lim, torque_Nm)) if torque_Nm == torque_Nm else 0.0
        self._torque_permille = max(-32768, min(32767, round(tau * 1000.0 / self.rated_torque_Nm)))

    def send_cycle(self) -> None:
        """Send RPDO1 (controlword, target torque), then SYNC; the daemon heartbeat when due.

        :raises DriverError: if the bus refuses a frame.
        """
        if self.network is None:
            raise DriverError("motor not started")
        _RPDO1.pack_into(self._rpdo_msg.data, 0, self._controlword,
                         self._torque_permille if self._expect_enabled else 0)
        try:
            self._bus.send(self._rpdo_msg)
            self._bus.send(self._sync_msg)
            now = time.monotonic()
            if now >= self._hb_next_s:
                self._hb_next_s = now + self.config.heartbeat_period_s
                self._bus.send(self._hb_msg)
        except can.CanError as exc:
            raise DriverError(f"CAN send failed: {exc}") from exc
        self.syncs_sent += 1

    def _on_frame(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self._rx.append((can_id, bytes(data), time.monotonic()))

    def _drain(self) -> bool:
        """Process received frames; latch faults. True if a TPDO arrived."""
        rx = self._rx
        if self._direct:
            now_s = time.monotonic()
            to_mono = now_s - time.time()
            try:
                while (msg := self._bus.recv(0)) is not None:
                    if not (msg.is_error_frame or msg.is_remote_frame):
                        t_s = msg.timestamp + to_mono
                        rx.append((msg.arbitration_id, msg.data, t_s if abs(t_s - now_s) < 1.0 else now_s))
            except (can.CanError, OSError) as exc:
                self._fault = self._fault or DriverError(f"CAN receive failed: {exc}")
        else:
            notifier = self.network.notifier
            if notifier is not None and (notifier.exception is not None or not (
                    self._handover or all(t.is_alive() for t in self._rx_threads))):
                self._fault = self._fault or DriverError(f"CAN receive thread died: {notifier.exception!r}")
        tpdo1, tpdo2, emcy, hb, sdo_tx = self._cobs
        rd, new = self.reading, False
        while rx:
            can_id, data, t_s = rx.popleft()
            if can_id == tpdo1 and len(data) >= 7:
                rd.statusword, rd.mode, pos = _TPDO1.unpack_from(data)
                rd.position_counts = pos
                rd.position_rad = pos * self._pos_scale
                rd.t_ns = round(t_s * 1e9)
                rd.t_s, new = seconds_from_ns(rd.t_ns), True
                self.tpdo1_received += 1
                self.state = decode_statusword(rd.statusword)
                if rd.statusword & 0x0800:
                    self._on_internal_limit(t_s)
                else:
                    self._limit_active = False
            elif can_id == tpdo2 and len(data) >= 6:
                vel, tq = _TPDO2.unpack_from(data)
                rd.velocity_units, rd.torque_permille = vel, tq
                rd.velocity_rad_s = vel * self._vel_scale
                rd.torque_Nm = tq * self.rated_torque_Nm / 1000.0
                rd.t_ns = round(t_s * 1e9)
                rd.t_s, new = seconds_from_ns(rd.t_ns), True
                self.tpdo2_received += 1
            elif can_id == hb and data:
                self._hb_last_s = t_s
                self.nmt_state = data[0]
                if data[0] != _NMT_OPERATIONAL and self._expect_enabled:
                    self._fault = self._fault or DriveFaultError(
                        f"drive {self.config.node_id} left NMT OPERATIONAL (heartbeat state 0x{data[0]:02X})")
            elif can_id == emcy:
                fault = decode_emcy(data, t_s)
                self.last_emcy = fault
                if not fault.is_reset:
                    logger.error("drive %d: %s", self.config.node_id, fault)
                    self._fault = self._fault or DriveFaultError(f"drive {self.config.node_id}: {fault}")
            elif can_id == sdo_tx and self._direct:
                self._sdo_reply = bytes(data)
        if new and self._expect_enabled:
            if self.state in (State402.FAULT, State402.FAULT_REACTION_ACTIVE):
                self._fault = self._fault or DriveFaultError(
                    f"drive {self.config.node_id} fault: {describe_statusword(rd.statusword)}"
                    + (f"; last {self.last_emcy}" if self.last_emcy else ""))
            elif self.state != State402.OPERATION_ENABLED or rd.mode != int(self.mode):
                self._fault = self._fault or DriveFaultError(
                    f"drive {self.config.node_id} left OPERATION ENABLED/{self.mode.name}: "
                    f"{describe_statusword(rd.statusword)}, mode {rd.mode}")
        limit_s = self.HEARTBEAT_LOSS_PERIODS * self.config.drive_heartbeat_period_s
        if self._hb_last_s is not None and time.monotonic() - self._hb_last_s > limit_s:
            self._fault = self._fault or HeartbeatLostError(
                f"drive {self.config.node_id} is gone (device loss): no heartbeat for more than "
                f"{self.HEARTBEAT_LOSS_PERIODS} periods ({limit_s * 1000:.0f} ms)")
        return new

    def _on_internal_limit(self, t_s: float) -> None:
        """Statusword bit 11: count the TPDO; warn on a rising edge (at most once a second)."""
        self.internal_limit_cycles += 1
        if not self._limit_active and t_s - self._limit_logged_s >= 1.0:
            self._limit_logged_s = t_s
            logger.warning("drive %d limits the torque (statusword bit 11, internal limit active; "
                           "0x6072 = %s per mille): command %.3f Nm", self.config.node_id,
                           self.safety_objects.get("0x6072", "?"),
                           self._torque_permille * self.rated_torque_Nm / 1000.0)
        self._limit_active = True

    def derivations(self) -> list[Derivation]:
        """How a log rebuilds the SI feedback from the logged wire values: exactly the
        conversions of the TPDO decoding (the drive's units: valid after :meth:`start`, or
        before it where the configuration states every unit).

        :raises DriverError: if the units are not known yet.
        """
        if self.drive_units is None:
            raise DriverError(f"drive {self.config.node_id}: units unknown before start()")
        return [Derivation("q_m_rad", "q_m_counts", scale_ops(self._pos_scale)),
                Derivation("dq_m_rad_s", "dq_m_units", scale_ops(self._vel_scale)),
                Derivation("tau_m_meas_Nm", "tau_m_meas_permille", motor_torque_ops(self.rated_torque_Nm)),
                Derivation("motor_t_s", "motor_t_ns", NS_TO_S)]

    def poll(self) -> MotorReading | None:
        """Drain received frames without blocking; the newest reading or None if no new TPDO.

        The returned object is reused and updated by later polls.

        :raises DriveFaultError: on EMCY, a fault in the statusword or the drive leaving OPERATION ENABLED.
        :raises HeartbeatLostError: when the drive heartbeat is missing for 3 periods.
        :raises DriverError: when the CAN receive thread died.
        """
        new = self._drain()
        if self._fault is not None:
            self._expect_enabled = False
            raise self._fault
        return self.reading if new else None

    def close(self) -> None:
        """Leave the drive restartable: disable, disarm its consumer heartbeat 0x1016, NMT
        pre-operational, then stop producing the daemon's heartbeat and release the bus.

        Best effort and bounded: a drive that is gone is given up within one heartbeat
        timeout (logged); nothing here raises.
        """
        if self.network is None:
            return
        nid = self.config.node_id
        self._begin_wait()
        try:
            self._check_alive()
            self.disable()
            self._sdo_now(0x1016, 1, 0)  # disarm before the daemon's heartbeat stops
            self.node.nmt.send_command(0x80)
        except Exception as exc:  # best effort: the bus or the drive may be gone
            logger.warning("drive %d: close: %s; the drive may fault on the lost heartbeat (0x8130), "
                           "which the next start-up resets", nid, exc)
        self._release()
