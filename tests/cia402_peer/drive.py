"""A second simulated CiA 402 drive, written from CiA 301 / CiA 402-2 only.

Independent of ``capstan.drivers.sim.drive`` and of capstan's state-machine table
(nothing from capstan is imported): its own EDS reader (:mod:`cia402_peer.od`), its own
SDO server, NMT slave, heartbeat producer/consumer, PDOs and device-control state
machine (:mod:`cia402_peer.device_control`). Its defaults are those of a drive out of the box that does *not* forgive
a careless master:

* it boots for ``boot_delay_s`` (silent: no NMT, no SDO) before its boot-up message;
* TPDO COB-IDs have bit 30 set (no RTR) and a write that clears it is aborted;
  mapping may only be written with the PDO invalid and sub-index 0 at zero;
* 0x6007 (abort connection option) = 0: a lost master heartbeat does not stop the
  motor; 0x6072 (max torque) = 100 per mille, the command is capped there and
  statusword bit 11 (internal limit active) is set;
* 0x1016 consumer heartbeat: on timeout EMCY 0x8130, 0x1029 sub 1 NMT reaction and
  the 0x6007 reaction (1 fault, 2 disable voltage, 3 quick stop);
* 0x605A quick-stop option (0-4: ends in SWITCH ON DISABLED, 5-8: stays in QUICK STOP
  ACTIVE, transition 16 allowed), 0x605B shutdown option (0 at once, 1 after a ramp);
* EMCY on the COB-ID of 0x1014, error code in 0x603F and history in 0x1003;
* units (CiA 402-2 factor group, :mod:`cia402_peer.units`): 0x6064 and 0x606C are served
  in the units 0x60A8/0x60A9 declare (the vendor EDS: tenths of a degree and rpm), from
  its internal increments (0x6063, motor encoder of ``encoder_increments`` per revolution,
  0x608F) and its motor speed, through the gear 0x6091; unit codes it does not know are
  refused on write (abort 0x06090030).

Runs in its own thread on its own python-can bus; :meth:`PeerDrive.close` re-raises
an error of that thread.
"""

from __future__ import annotations

import struct
import threading
import time
from enum import IntEnum

import can

from cia402_peer.device_control import DeviceControl, Ds402
from cia402_peer.od import Entry, load_eds
from cia402_peer.sdo_server import (ABORT_RANGE, ABORT_STATE, SdoAbort, handle_request)
from cia402_peer.units import UnitError, user_value


class Nmt(IntEnum):
    BOOTING = -1
    STOPPED = 0x04
    OPERATIONAL = 0x05
    PRE_OPERATIONAL = 0x7F


_MODE_BIT = {1: 0, 3: 2, 4: 3, 6: 5, 7: 6, 8: 7, 9: 8, 10: 9}


class PeerDrive(DeviceControl):
    """CiA 402 drive on ``bus`` with node id ``node_id`` and the object dictionary of ``eds``.

    :param boot_delay_s: time from :meth:`start` to the boot-up message.
    :param abort_connection_option: 0x6007 at power-on (0: no action).
    :param max_torque_permille: 0x6072 at power-on.
    :param emcy_cob_id: 0x1014 at power-on (default 0x80 + node id).
    :param ramp_s: duration of quick-stop and shutdown ramps.
    :param encoder_increments: increments per revolution of the motor's encoder (0x608F sub 1).
    :param power_on: further object values at power-on, ``{(index, sub): value}`` (a drive
        set up by its vendor tool, e.g. ``{(0x60A9, 0): 0xFDB44700}``).
    """

    def __init__(self, bus: can.BusABC, node_id: int, eds: str, boot_delay_s: float = 0.0,
                 abort_connection_option: int = 0, max_torque_permille: int = 100,
                 emcy_cob_id: int | None = None, ramp_s: float = 0.02, encoder_increments: int = 4096,
                 power_on: dict[tuple[int, int], int] | None = None) -> None:
        self.bus, self.node_id, self.eds = bus, node_id, eds
        self.boot_delay_s, self.ramp_s = boot_delay_s, ramp_s
        self._power_on = {(0x6007, 0): abort_connection_option, (0x6072, 0): max_torque_permille,
                          (0x608F, 1): encoder_increments, (0x608F, 2): 1, **(power_on or {})}
        if emcy_cob_id is not None:
            self._power_on[(0x1014, 0)] = emcy_cob_id
        self.lock = threading.RLock()
        self.error: BaseException | None = None
        self.emcy_sent: list[int] = []
        self.boot_ups = 0
        #: internal position (0x6063) [increments of the motor encoder]
        self.position_counts = 1000
        #: motor speed the drive measures [motor revolutions per second]
        self.motor_speed_rev_s = 0.0
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="cia402-peer", daemon=True)
        self._power_up(time.monotonic())

    # ------------------------------------------------------------ power / NMT
    def _power_up(self, now: float) -> None:
        self.od: dict[tuple[int, int], Entry] = load_eds(self.eds, self.node_id)
        for key, value in self._power_on.items():
            if key in self.od:
                self.od[key].value = value
        for n in range(512):  # TPDOs: no RTR (bit 30 set)
            e = self.od.get((0x1800 + n, 1))
            if e is not None:
                e.value |= 0x40000000
        self.nmt = Nmt.BOOTING
        self.state = Ds402.NOT_READY
        self._boot_at = now + self.boot_delay_s
        self._cw = 0
        self._mode_display = 0
        self._target = 0
        self._applied = 0.0
        self._ramp: tuple[str, float, float] | None = None  # (kind, t_start, torque at start)
        self._hb_next = 0.0
        self._consumer_last: dict[int, float | None] = {}
        self._pending_rpdo: dict[int, bytes] = {}
        self._sync_count = 0
        self.internal_limit = False

    def _boot(self, now: float) -> None:
        self.nmt = Nmt.PRE_OPERATIONAL
        self.state = Ds402.SWITCH_ON_DISABLED
        self.boot_ups += 1
        self._send(0x700 + self.node_id, b"\x00")
        self._hb_next = now

    def _on_nmt(self, data: bytes, now: float) -> None:
        if len(data) < 2 or data[1] not in (0, self.node_id):
            return
        cs = data[0]
        if cs == 0x01:
            self.nmt = Nmt.OPERATIONAL
        elif cs == 0x02:
            self.nmt = Nmt.STOPPED
        elif cs == 0x80:
            self.nmt = Nmt.PRE_OPERATIONAL
        elif cs in (0x81, 0x82):  # reset node / communication: reboot at once
            keep = {k: e.value for k, e in self.od.items() if cs == 0x82 and k[0] >= 0x2000}
            self.boot_delay_s, delay = 0.0, self.boot_delay_s
            self._power_up(now)
            self.boot_delay_s = delay
            for k, v in keep.items():
                self.od[k].value = v

    # ------------------------------------------------------------------ API
    def start(self) -> "PeerDrive":
        self._power_up(time.monotonic())
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop = True
        if self._thread.is_alive():
            self._thread.join(2)
        if self.error is not None:
            raise self.error

    def value(self, index: int, sub: int = 0) -> int:
        with self.lock:
            return self.od[(index, sub)].value

    @property
    def applied_torque_permille(self) -> float:
        """Torque the power stage produces now [per mille of rated]."""
        with self.lock:
            return self._applied

    def inject_fault(self, code: int, register: int = 0x01) -> None:
        with self.lock:
            self._fault(code, register)

    # -------------------------------------------------------------- the loop
    def _run(self) -> None:
        try:
            while not self._stop:
                msg = self.bus.recv(0.0005)
                now = time.monotonic()
                with self.lock:
                    if msg is not None and not msg.is_error_frame and self.nmt != Nmt.BOOTING:
                        self._on_frame(msg.arbitration_id, bytes(msg.data), now)
                    self._tick(now)
        except BaseException as exc:  # re-raised by close()
            self.error = exc

    def _send(self, cob: int, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=cob, data=data, is_extended_id=False))

    def _on_frame(self, cob: int, data: bytes, now: float) -> None:
        nid = self.node_id
        if cob == 0:
            self._on_nmt(data, now)
        elif cob == 0x600 + nid and self.nmt != Nmt.STOPPED:
            reply = handle_request(data, self.od, self._read, self._write)
            if reply is not None:
                self._send(0x580 + nid, reply)
        elif cob == 0x80 and self.nmt == Nmt.OPERATIONAL:
            self._on_sync()
        elif 0x701 <= cob <= 0x77F and cob - 0x700 in self._consumers():
            self._consumer_last[cob - 0x700] = now
        elif self.nmt == Nmt.OPERATIONAL:
            for n, rcob, ttype in self._rpdos():
                if cob == rcob:
                    if ttype <= 240:
                        self._pending_rpdo[n] = data   # taken over at the next SYNC
                    else:
                        self._apply_rpdo(n, data)

    def _tick(self, now: float) -> None:
        if self.nmt == Nmt.BOOTING:
            if now >= self._boot_at:
                self._boot(now)
            return
        period = self.od[(0x1017, 0)].value / 1000.0
        if period > 0 and now >= self._hb_next:
            self._hb_next = max(self._hb_next + period, now - period)
            self._send(0x700 + self.node_id, bytes([int(self.nmt)]))
        for node, timeout in self._consumers().items():
            last = self._consumer_last.get(node)
            if last is not None and now - last > timeout:
                self._consumer_last[node] = None  # re-armed by the next heartbeat
                self._heartbeat_event()
        if self.state == Ds402.FAULT_REACTION_ACTIVE:
            self.state = Ds402.FAULT
        self._update_torque(now)

    # ------------------------------------------------------- heartbeat consumer
    def _consumers(self) -> dict[int, float]:
        out = {}
        for k in range(1, self.od.get((0x1016, 0), Entry(0, 0, "", 1, False, "ro", False, 0, 0)).value + 1):
            word = self.od[(0x1016, k)].value
            node, ms = (word >> 16) & 0x7F, word & 0xFFFF
            if node and ms:
                out[node] = ms / 1000.0
        return out

    def _heartbeat_event(self) -> None:
        self._record_error(0x8130)
        self._emcy(0x8130, 0x11)
        behaviour = self.od_value(0x1029, 1, 0)
        if behaviour == 0 and self.nmt == Nmt.OPERATIONAL:
            self.nmt = Nmt.PRE_OPERATIONAL
        elif behaviour == 2:
            self.nmt = Nmt.STOPPED
        option = self.od_value(0x6007, 0, 0)
        if option == 1:
            self._fault(0x8130, 0x11, emcy=False)
        elif option == 2 and self.state not in (Ds402.FAULT, Ds402.FAULT_REACTION_ACTIVE):
            self.state = Ds402.SWITCH_ON_DISABLED
        elif option == 3 and self.state == Ds402.OPERATION_ENABLED:
            self._quick_stop(time.monotonic())

    # ------------------------------------------------------------- faults
    def _record_error(self, code: int) -> None:
        n = self.od[(0x1003, 0)].value
        depth = max(k for i, k in self.od if i == 0x1003)
        for k in range(min(n + 1, depth), 1, -1):
            self.od[(0x1003, k)].value = self.od[(0x1003, k - 1)].value
        self.od[(0x1003, 1)].value = code
        self.od[(0x1003, 0)].value = min(n + 1, depth)

    def _emcy(self, code: int, register: int) -> None:
        cob = self.od[(0x1014, 0)].value
        self.emcy_sent.append(code)
        if not cob & 0x80000000:
            self._send(cob & 0x7FF, struct.pack("<HB5s", code, register, b""))

    def _fault(self, code: int, register: int, emcy: bool = True) -> None:
        self.od[(0x603F, 0)].value = code
        self.od[(0x1001, 0)].value = register
        if emcy:
            self._record_error(code)
            self._emcy(code, register)
        if self.state not in (Ds402.FAULT, Ds402.FAULT_REACTION_ACTIVE):
            self.state = Ds402.FAULT_REACTION_ACTIVE

    # -------------------------------------------------------------- objects
    def _read(self, e: Entry) -> int:
        i = e.index
        if i == 0x6041:
            return self.statusword()
        if i == 0x6061:
            return self._mode_display
        if i == 0x6077:
            return round(self._applied)
        if i == 0x6064:
            return self._user(0x60A8, self.position_counts)
        if i == 0x6063:
            return self.position_counts
        if i == 0x606C:
            return self._user(0x60A9, self.motor_speed_rev_s * self.od_value(0x608F, 1, 0)
                              / max(1, self.od_value(0x608F, 2, 1)))
        if i == 0x6071:
            return self._target
        return e.value

    def _user(self, si_index: int, increments: float) -> int:
        """``increments`` (per second, for 0x60A9) of the motor encoder in the unit ``si_index`` declares."""
        gear = (self.od_value(0x6091, 1, 1), self.od_value(0x6091, 2, 1))
        enc = (self.od_value(0x608F, 1, 0), self.od_value(0x608F, 2, 1))
        return user_value(self.od_value(si_index, 0, 0x00B50000 if si_index == 0x60A8 else 0x00B50300),
                          increments, enc, gear)

    def _pdo_valid(self, comm: int) -> bool:
        return not self.od[(comm, 1)].value & 0x80000000

    def _write(self, e: Entry, v: int) -> None:
        i, s, now = e.index, e.sub, time.monotonic()
        if not e.in_range(v):
            raise SdoAbort(ABORT_RANGE)
        if (0x1400 <= i <= 0x15FF or 0x1800 <= i <= 0x19FF) and s == 1:
            if v & 0x20000000 or (i >= 0x1800 and not v & 0x40000000):
                raise SdoAbort(ABORT_RANGE)      # no 29-bit ids; TPDO without RTR: bit 30 stays set
            if not (v | e.value) & 0x80000000 and (v ^ e.value) & 0x7FF:
                raise SdoAbort(ABORT_RANGE)      # COB-ID of a valid PDO cannot change
        elif 0x1600 <= i <= 0x17FF or 0x1A00 <= i <= 0x1BFF:
            comm = i - 0x200
            if self._pdo_valid(comm) or (s > 0 and self.od[(i, 0)].value != 0):
                raise SdoAbort(ABORT_STATE)
            if s == 0:
                bits = 0
                for k in range(1, v + 1):
                    word = self.od[(i, k)].value
                    target = self.od.get((word >> 16, (word >> 8) & 0xFF))
                    if target is None or not target.mappable:
                        raise SdoAbort(0x06040041)
                    bits += word & 0xFF
                if bits > 64:
                    raise SdoAbort(0x06040042)
        elif i == 0x6060:
            supported = self.od[(0x6502, 0)].value
            if v not in _MODE_BIT or not supported >> _MODE_BIT[v] & 1:
                raise SdoAbort(ABORT_RANGE)
            self._mode_display = v
        elif i == 0x6007 and not 0 <= v <= 3:
            raise SdoAbort(ABORT_RANGE)
        elif i == 0x605A and not 0 <= v <= 8:
            raise SdoAbort(ABORT_RANGE)
        elif i == 0x1029 and not 0 <= v <= 2:
            raise SdoAbort(ABORT_RANGE)
        elif i in (0x608F, 0x6091, 0x60A8, 0x60A9):
            old, e.value = e.value, v
            try:
                self._user(0x60A8, 0)
                self._user(0x60A9, 0)
            except UnitError:
                e.value = old
                raise SdoAbort(ABORT_RANGE) from None
        e.value = v
        if i == 0x6040:
            self._controlword(v, now)
        elif i == 0x6071:
            self._target = v
        elif i == 0x1016:
            self._consumer_last = {}
        elif i == 0x1017:
            self._hb_next = now

    # ------------------------------------------------------------------ PDOs
    def _rpdos(self) -> list[tuple[int, int, int]]:
        out = []
        for n in range(512):
            if (0x1400 + n, 1) not in self.od:
                break
            if self._pdo_valid(0x1400 + n):
                out.append((n, self.od[(0x1400 + n, 1)].value & 0x7FF, self.od[(0x1400 + n, 2)].value))
        return out

    def _mapped(self, mapping: int) -> list[Entry]:
        out = []
        for k in range(1, self.od[(mapping, 0)].value + 1):
            word = self.od[(mapping, k)].value
            out.append(self.od[(word >> 16, (word >> 8) & 0xFF)])
        return out

    def _apply_rpdo(self, n: int, data: bytes) -> None:
        entries = self._mapped(0x1600 + n)
        if len(data) < sum(e.size for e in entries):
            self._emcy(0x8210, 0x11)
            return
        off = 0
        for e in entries:
            self._write(e, e.decode(data[off:off + e.size]))
            off += e.size

    def _on_sync(self) -> None:
        for n, data in sorted(self._pending_rpdo.items()):
            self._apply_rpdo(n, data)
        self._pending_rpdo.clear()
        self._sync_count += 1
        for n in range(512):
            comm = 0x1800 + n
            if (comm, 1) not in self.od:
                break
            ttype = self.od[(comm, 2)].value
            if self._pdo_valid(comm) and 1 <= ttype <= 240 and self._sync_count % ttype == 0:
                payload = b"".join(e.encode(self._read(e)) for e in self._mapped(0x1A00 + n))
                self._send(self.od[(comm, 1)].value & 0x7FF, payload)
