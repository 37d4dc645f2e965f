"""A simulated CiA 402 servo drive: a CANopen slave the daemon cannot tell from hardware.

The rig process (driven by the simulated plant of :mod:`capstan.models`) owns one
:class:`SimDrive` on a CAN bus shared with the daemon (``capstan_unix`` on machines
without SocketCAN). The drive

* answers SDO from an object dictionary loaded from an EDS (the project ships
  ``drivers/data/capstan_drive.eds``; vendor EDS files work too),
* follows NMT commands, sends a boot-up frame and produces its heartbeat (0x1017),
* runs the DS402 state machine of :mod:`capstan.drivers.canopen.cia402` on the controlword
  (SDO or RPDO), accepts only modes listed in 0x6502,
* sends its SYNC-type TPDOs on every (n-th) SYNC with the PDO mapping the master
  configured, and applies RPDOs with that mapping,
* watches the master's heartbeat (consumer entries of 0x1016): a missing heartbeat
  sends EMCY 0x8130 and reacts as 0x6007 says (1, also without the object: FAULT;
  2: disable voltage; 3: quick stop; 0: nothing),
* caps the torque at 0x6072 (max torque) and then sets statusword bit 11,
* faults on :meth:`SimDrive.inject_fault` (EMCY with the given code).

Units on the wire are those the drive's object dictionary declares, as a real drive
serves them: 0x6064 in the unit of 0x60A8 (SI unit position), 0x606C in the unit of 0x60A9
(SI unit velocity) — whole rpm for the Nanotec C5-E EDS, increments and increments/s for
capstan's own — each an integer, so the unit's quantisation happens on the wire; increments
count the motor encoder (0x608F, ``encoder_counts_per_rev``), angle units are of the shaft
behind the gear 0x6091; 0x6071/0x6077 in per mille of the rated torque (0x6076). A master
may write 0x608F/0x6091/0x60A8/0x60A9 over SDO; a unit code the drive does not know is
refused (abort 0x06090030). The positions and speeds given to :meth:`SimDrive.set_feedback`
are the motor shaft's.

CAN timing (optional): with a :class:`~capstan.models.plant.command_path.CommandPath` the
drive takes its target torque over at each SYNC (CiA 402 synchronous RPDO) and passes it
through the path, which delays it (nominal delay plus seeded jitter, in order) or loses it
(the motor keeps the previous target); without one the target is applied as the RPDO arrives.

Threading: CAN reception (SDO, NMT, SYNC, RPDO) runs in the canopen notifier thread,
:meth:`service` and :meth:`set_feedback` in the rig thread; a lock guards the state.
"""

from __future__ import annotations

import logging
import math
import struct
import threading
from typing import Any

import can
import canopen
from canopen.sdo import SdoAbortedError

from capstan.drivers.canopen.cia402 import (OpMode, State402, STATUSWORD_BITS, SUPPORTED_MODE_BIT,
                            decode_controlword, drive_transition)
from capstan.drivers.canopen.emcy import encode_emcy
from capstan.drivers.sim.wire_units import wire_units_per_rad
from capstan.models.plant.command_path import CommandPath
from capstan.models.common.errors import ConfigError

logger = logging.getLogger(__name__)

NMT_INITIALISING = 0x00
NMT_STOPPED = 0x04
NMT_OPERATIONAL = 0x05
NMT_PRE_OPERATIONAL = 0x7F
_NMT_CMD = {0x01: NMT_OPERATIONAL, 0x02: NMT_STOPPED, 0x80: NMT_PRE_OPERATIONAL}

EMCY_HEARTBEAT = 0x8130
_ABORT_VALUE_RANGE = 0x06090030
_TORQUE_MODES = (int(OpMode.PROFILE_TORQUE), int(OpMode.CYCLIC_SYNC_TORQUE))


class SimDrive:
    """Simulated CiA 402 drive on a CAN bus.

    :param bus_or_network: a python-can bus (a canopen Network is created and
        connected on it) or an already connected :class:`canopen.Network`.
    :param node_id: CANopen node id 1..127.
    :param eds_path: EDS/DCF of the drive.
    :param rated_torque_Nm: rated torque; the unit of 0x6071/0x6077 is 1/1000 of it.
        Stored in 0x6076 [mNm] where the EDS has that object.
    :param encoder_counts_per_rev: increments of the motor encoder per revolution (the motor's
        property: stored in 0x608F where the EDS has it; quantises the position).
    :param si_units: power-on values of 0x60A8/0x60A9 overriding the EDS
        (``{0x60A9: 0xFDB44700}``: milli-rpm), as a drive configured by its vendor tool.
    :param supported_modes: value for 0x6502 overriding the EDS (e.g. ``1 << 9`` CST only).
    :param command_path: CAN timing of the command path, one push per SYNC with the target in
        per mille (None: the target is applied as the RPDO arrives).
    :raises ConfigError: for an invalid node id or rated torque, or units the drive cannot serve.
    """

    def __init__(self, bus_or_network: can.BusABC | canopen.Network, node_id: int, eds_path: str,
                 rated_torque_Nm: float, encoder_counts_per_rev: int = 1 << 17,
                 si_units: dict[int, int] | None = None, supported_modes: int | None = None,
                 command_path: CommandPath | None = None) -> None:
        if not 1 <= int(node_id) <= 127:
            raise ConfigError("sim_drive.node_id", f"must be 1..127, got {node_id}")
        if not rated_torque_Nm > 0:
            raise ConfigError("sim_drive.rated_torque_Nm", f"must be > 0, got {rated_torque_Nm}")
        if not int(encoder_counts_per_rev) >= 1:
            raise ConfigError("sim_drive.encoder_counts_per_rev", f"must be >= 1, got {encoder_counts_per_rev}")
        self.node_id = int(node_id)
        self.rated_torque_Nm = float(rated_torque_Nm)
        self.encoder_counts_per_rev = int(encoder_counts_per_rev)
        self.command_path = command_path
        self._applied_permille = 0
        self._lock = threading.RLock()
        if isinstance(bus_or_network, canopen.Network):
            self.network = bus_or_network
            self._own_network = False
        else:
            self.network = canopen.Network(bus_or_network)
            self.network.NOTIFIER_CYCLE = 0.05
            self.network.connect()
            self._own_network = True
        od = canopen.import_od(eds_path, self.node_id)
        self.node = canopen.LocalNode(self.node_id, od)
        # NMT and heartbeat are handled here (driven by service(), no timer thread)
        self.node._write_callbacks.remove(self.node.nmt.on_write)
        self.network[self.node_id] = self.node  # subscribes the SDO server
        self.network.unsubscribe(0, self.node.nmt.on_command)
        self.node.add_write_callback(self._on_write)
        self.node.add_read_callback(self._on_read)
        if 0x6076 in od:
            self._store(0x6076, 0, round(self.rated_torque_Nm * 1000))
        if supported_modes is not None:
            self._store(0x6502, 0, int(supported_modes))
        if self._has(0x608F):
            self._store(0x608F, 1, self.encoder_counts_per_rev)
            self._store(0x608F, 2, 1)
        for index, code in (si_units or {}).items():
            self._store(index, 0, code)
        try:
            self._update_scales()
        except ValueError as exc:
            raise ConfigError("sim_drive.si_units", str(exc)) from exc

        self.nmt_state = NMT_INITIALISING
        self.state = State402.SWITCH_ON_DISABLED
        self.mode_display = 0
        self.controlword = 0
        self.target_torque_permille = 0
        self.error_code = 0
        self.faults_raised: list[int] = []
        self._position_rad = 0.0
        self._velocity_rad_s = 0.0
        self._torque_Nm = 0.0
        self._hb_period_s = 0.0
        self._hb_next_s: float | None = None
        self._consumers: dict[int, float] = {}
        self._consumer_seen: dict[int, bool] = {}
        self._consumer_last_s: dict[int, float | None] = {}
        self._rpdos: dict[int, list[tuple[int, int, int, int]]] = {}
        self._tpdos: list[tuple[int, int, list[tuple[int, int]]]] = []
        self._sync_count = 0
        self.network.subscribe(0, self._on_nmt)
        self.network.subscribe(0x80, self._on_sync)
        self._boot()

    # ----------------------------------------------------------------- helpers
    def _store(self, index: int, subindex: int, value: int) -> None:
        obj = self.node._find_object(index, subindex)
        self.node.data_store.setdefault(index, {})[subindex] = obj.encode_raw(value)

    def _value(self, index: int, subindex: int) -> Any:
        obj = self.node._find_object(index, subindex)
        return obj.decode_raw(self.node.get_data(index, subindex))

    def _has(self, index: int) -> bool:
        return index in self.node.object_dictionary

    def _update_scales(self) -> None:
        """Wire units per motor-shaft rad (rad/s) from the dictionary's unit objects.

        :raises ValueError: for units the drive cannot serve.
        """
        self._pos_units_per_rad, self._vel_units_per_rad_s = wire_units_per_rad(
            lambda i, k: self._value(i, k), self._has, self.encoder_counts_per_rev)
        self._counts_per_rad = self.encoder_counts_per_rev / (2 * math.pi)

    def _boot(self) -> None:
        self.network.send_message(0x700 + self.node_id, b"\x00")
        self.nmt_state = NMT_PRE_OPERATIONAL
        self._hb_period_s = self._value(0x1017, 0) / 1000.0 if self._has(0x1017) else 0.0
        self._load_consumers()

    def supported_modes(self) -> int:
        """Value of 0x6502 (0 if the dictionary lacks it)."""
        return int(self._value(0x6502, 0)) if self._has(0x6502) else 0

    # -------------------------------------------------------------- rig API
    @property
    def torque_command_Nm(self) -> float:
        """Torque the plant should apply now [Nm]: 0 unless OPERATION ENABLED in a torque mode."""
        with self._lock:
            if (self.nmt_state == NMT_OPERATIONAL and self.state == State402.OPERATION_ENABLED
                    and self.mode_display in _TORQUE_MODES):
                lim = self._max_torque_permille()
                target = self.target_torque_permille if self.command_path is None else self._applied_permille
                return max(-lim, min(lim, target)) * self.rated_torque_Nm / 1000.0
            return 0.0

    def _max_torque_permille(self) -> int:
        """0x6072 (max torque) [per mille of rated]; no limit where the dictionary lacks it."""
        return int(self._value(0x6072, 0)) if self._has(0x6072) else 32767

    def set_feedback(self, position_rad: float, velocity_rad_s: float, torque_Nm: float) -> None:
        """Motor state of the plant [rad, rad/s, Nm], sent in the next TPDO."""
        self._position_rad = position_rad
        self._velocity_rad_s = velocity_rad_s
        self._torque_Nm = torque_Nm

    def inject_fault(self, code: int, register: int = 0x01) -> None:
        """Fault the drive now: FAULT state, torque off, EMCY ``code`` sent."""
        with self._lock:
            self._fault(code, register)

    def service(self, now_s: float) -> None:
        """Periodic duties, called every ms by the rig: heartbeat producer and consumer watchdog.

        :param now_s: the rig's clock [s] (any monotonic time base, used consistently).
        """
        with self._lock:
            if self.state == State402.FAULT_REACTION_ACTIVE:
                self.state = State402.FAULT  # transition 14: reaction (torque off) done
            if self.state == State402.QUICK_STOP_ACTIVE and self._quick_stop_to_disabled():
                self.state = State402.SWITCH_ON_DISABLED  # transition 12 after the stop
            # drift-free schedule; 1 us slack absorbs rounding of the rig's clock
            if self._hb_period_s > 0 and (self._hb_next_s is None or now_s >= self._hb_next_s - 1e-6):
                late = self._hb_next_s is None or now_s - self._hb_next_s > self._hb_period_s
                self._hb_next_s = (now_s if late else self._hb_next_s) + self._hb_period_s
                self.network.send_message(0x700 + self.node_id, bytes([self.nmt_state]))
            for node, timeout_s in self._consumers.items():
                if self._consumer_seen.get(node):
                    self._consumer_seen[node] = False
                    self._consumer_last_s[node] = now_s
                last = self._consumer_last_s.get(node)
                if last is not None and now_s - last > timeout_s + 1e-6:
                    self._consumer_last_s[node] = None  # re-armed by the next heartbeat
                    logger.warning("node %d: heartbeat of node %d lost", self.node_id, node)
                    self._heartbeat_event()

    def _heartbeat_event(self) -> None:
        """Consumer heartbeat timeout: the reaction 0x6007 asks for (CiA 402-2; 1 where absent)."""
        option = int(self._value(0x6007, 0)) if self._has(0x6007) else 1
        if option == 1:
            self._fault(EMCY_HEARTBEAT, 0x11)
            return
        self.network.send_message(0x80 + self.node_id, encode_emcy(EMCY_HEARTBEAT, 0x11))
        if option == 2 and self.state not in (State402.FAULT, State402.FAULT_REACTION_ACTIVE):
            self.state = State402.SWITCH_ON_DISABLED
        elif option == 3 and self.state == State402.OPERATION_ENABLED:
            self.state = State402.QUICK_STOP_ACTIVE
        if self.state != State402.OPERATION_ENABLED:
            self.target_torque_permille = 0

    def _quick_stop_to_disabled(self) -> bool:
        option = int(self._value(0x605A, 0)) if self._has(0x605A) else 2
        return option in (1, 2, 3)

    # --------------------------------------------------------- fault handling
    def _fault(self, code: int, register: int) -> None:
        self.error_code = code
        self.faults_raised.append(code)
        self.target_torque_permille = 0
        if self.state not in (State402.FAULT, State402.FAULT_REACTION_ACTIVE):
            self.state = State402.FAULT_REACTION_ACTIVE  # transition 13
        if self._has(0x1001):
            self._store(0x1001, 0, register)
        if self._has(0x603F):
            self._store(0x603F, 0, code)
        self.network.send_message(0x80 + self.node_id, encode_emcy(code, register))

    # ------------------------------------------------------------ NMT / SYNC
    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) < 2 or data[1] not in (0, self.node_id):
            return
        cmd = data[0]
        with self._lock:
            if cmd in (0x81, 0x82):
                self._boot()
                return
            new = _NMT_CMD.get(cmd)
            if new is None:
                return
            if new == NMT_OPERATIONAL:
                self._build_pdos()
            self.nmt_state = new

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self._lock:
            if self.nmt_state != NMT_OPERATIONAL:
                return
            self._sync_count += 1
            if self.command_path is not None:
                self._take_over_target()
            frames = []
            for cob_id, ttype, entries in self._tpdos:
                if ttype == 0 or self._sync_count % ttype == 0:
                    frames.append((cob_id, b"".join(self.node.get_data(i, s) for i, s in entries)))
        for cob_id, payload in frames:
            self.network.send_message(cob_id, payload)

    def _take_over_target(self) -> None:
        """At a SYNC: the current target (0 unless enabled) enters the command path; what it
        delivers now reaches the motor."""
        target = self.target_torque_permille if self.state == State402.OPERATION_ENABLED else 0
        self._applied_permille = round(self.command_path.push(float(target)))

    def _build_pdos(self) -> None:
        for cob_id in list(self._rpdos):
            self.network.unsubscribe(cob_id, self._on_rpdo)
        self._rpdos.clear()
        self._tpdos.clear()
        for n in range(512):
            comm, mapping = 0x1400 + n, 0x1600 + n
            if not (self._has(comm) and self._has(mapping)):
                break
            cob_id = int(self._value(comm, 1))
            if cob_id & 0x80000000:
                continue
            entries, offset = [], 0
            for idx, sub, nbytes in self._mapping(mapping):
                entries.append((idx, sub, offset, nbytes))
                offset += nbytes
            self._rpdos[cob_id & 0x7FF] = entries
            self.network.subscribe(cob_id & 0x7FF, self._on_rpdo)
        for n in range(512):
            comm, mapping = 0x1800 + n, 0x1A00 + n
            if not (self._has(comm) and self._has(mapping)):
                break
            cob_id = int(self._value(comm, 1))
            ttype = int(self._value(comm, 2))
            if cob_id & 0x80000000 or ttype > 240:
                continue  # only synchronous TPDOs are produced
            self._tpdos.append((cob_id & 0x7FF, ttype,
                                [(i, s) for i, s, _ in self._mapping(mapping)]))

    def _mapping(self, index: int) -> list[tuple[int, int, int]]:
        out = []
        for k in range(1, int(self._value(index, 0)) + 1):
            word = int(self._value(index, k))
            idx, sub, bits = word >> 16, (word >> 8) & 0xFF, word & 0xFF
            out.append((idx, sub, bits // 8))
        return out

    def _on_rpdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        entries = self._rpdos.get(can_id)
        if entries is None or self.nmt_state != NMT_OPERATIONAL:
            return
        for idx, sub, offset, nbytes in entries:
            if idx < 0x1000:
                continue  # dummy mapping
            try:
                self.node.set_data(idx, sub, bytes(data[offset:offset + nbytes]))
            except SdoAbortedError as exc:
                logger.warning("RPDO 0x%03X: 0x%04X:%d refused (abort 0x%08X)", can_id, idx, sub, exc.code)

    # ----------------------------------------------------- object callbacks
    def _on_write(self, index: int, subindex: int, od: Any, data: bytes, **_: Any) -> None:
        with self._lock:
            if index == 0x6040:
                (cw,) = struct.unpack("<H", data)
                self._apply_controlword(cw)
            elif index == 0x6071:
                (self.target_torque_permille,) = struct.unpack("<h", data)
            elif index == 0x6060:
                (mode,) = struct.unpack("<b", data)
                bit = SUPPORTED_MODE_BIT.get(OpMode(mode)) if mode in OpMode._value2member_map_ else None
                if bit is None or not self.supported_modes() >> bit & 1:
                    raise SdoAbortedError(_ABORT_VALUE_RANGE)
                self.mode_display = mode
            elif index == 0x1017:
                (ms,) = struct.unpack("<H", data)
                self._hb_period_s = ms / 1000.0
                self._hb_next_s = None
            elif index == 0x1016 and subindex > 0:
                self.node.data_store.setdefault(index, {})[subindex] = bytes(data)
                self._load_consumers()
            elif index in (0x608F, 0x6091, 0x60A8, 0x60A9):
                store = self.node.data_store.setdefault(index, {})
                old = store.get(subindex)
                store[subindex] = bytes(data)
                try:
                    self._update_scales()
                except ValueError:
                    if old is None:
                        del store[subindex]
                    else:
                        store[subindex] = old
                    raise SdoAbortedError(_ABORT_VALUE_RANGE) from None

    def _load_consumers(self) -> None:
        for node in self._consumers:
            self.network.unsubscribe(0x700 + node, self._on_consumer_heartbeat)
        self._consumers.clear()
        if not self._has(0x1016):
            return
        for k in range(1, int(self._value(0x1016, 0)) + 1):
            word = int(self._value(0x1016, k))
            node, ms = (word >> 16) & 0x7F, word & 0xFFFF
            if node and ms:
                self._consumers[node] = ms / 1000.0
                self._consumer_last_s[node] = None
                self.network.subscribe(0x700 + node, self._on_consumer_heartbeat)

    def _on_consumer_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self._consumer_seen[can_id - 0x700] = True

    def _apply_controlword(self, cw: int) -> None:
        command = decode_controlword(cw, self.controlword)
        self.controlword = cw
        t = drive_transition(self.state, command)
        if t is not None:
            self.state = t.target
            if t.number == 15:
                self.error_code = 0
                if self._has(0x1001):
                    self._store(0x1001, 0, 0)
                self.network.send_message(0x80 + self.node_id, encode_emcy(0, 0))
        if self.state != State402.OPERATION_ENABLED:
            self.target_torque_permille = 0

    def statusword(self) -> int:
        """Statusword (0x6041) of the current state: bits 0-6, remote (9), CST follows (12)."""
        sw = STATUSWORD_BITS[self.state] | 0x0200
        if self.state == State402.OPERATION_ENABLED and self.mode_display in _TORQUE_MODES:
            sw |= 0x1000
            if abs(self.target_torque_permille) > self._max_torque_permille():
                sw |= 0x0800  # internal limit active: the command is capped at 0x6072
        return sw

    def _on_read(self, index: int, subindex: int, od: Any, **_: Any) -> int | None:
        if index == 0x6041:
            return self.statusword()
        if index == 0x6061:
            return self.mode_display
        if index == 0x6064:  # the encoder's increments, then the declared unit: both quantise
            counts = round(self._position_rad * self._counts_per_rad)
            return _wrap_i32(round(counts / self._counts_per_rad * self._pos_units_per_rad))
        if index == 0x606C:
            return _wrap_i32(round(self._velocity_rad_s * self._vel_units_per_rad_s))
        if index == 0x6077:
            return max(-32768, min(32767, round(self._torque_Nm / self.rated_torque_Nm * 1000)))
        if index == 0x6071:
            return self.target_torque_permille
        if index == 0x6040:
            return self.controlword
        return None

    def close(self) -> None:
        """Leave the bus (disconnects the network if this drive created it)."""
        self.network.unsubscribe(0, self._on_nmt)
        self.network.unsubscribe(0x80, self._on_sync)
        if self._own_network:
            self.network.disconnect()


def _wrap_i32(x: int) -> int:
    return (x + 0x80000000) % 0x100000000 - 0x80000000
