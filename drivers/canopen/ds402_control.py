"""The DS402 device-control side of :class:`~capstan.drivers.canopen.motor.CanopenMotor`.

:class:`Ds402Control` walks the drive's state machine (transition table of
:mod:`capstan.drivers.canopen.cia402`) one controlword per cycle, with RPDO, SYNC and the
daemon heartbeat sent every cycle meanwhile (``_step``). It never trusts a stale TPDO:
each walk starts from the statusword read over SDO now, and while no TPDO arrives
(a drive outside NMT OPERATIONAL sends none) the statusword is read again, and the
controlword also written, over SDO. A drive whose heartbeat stopped is given up within
that heartbeat timeout (:class:`~capstan.models.common.errors.DeviceLostError`).

SDO while the cyclic frames run (:meth:`Ds402Control._sdo_now`): through canopen's client
during start-up, afterwards as single expedited frames on the direct receive path
(:mod:`capstan.drivers.canopen.sdo_direct`).
"""

from __future__ import annotations

import logging
import math
import time

import can
import canopen

from capstan.drivers.canopen.cia402 import (CONTROLWORD, Command402, OpMode, State402, decode_statusword,
                                            describe_statusword, path_to)
from capstan.drivers.canopen.config import MotorConfig
from capstan.drivers.canopen.sdo_access import sdo_read, sdo_write
from capstan.drivers.canopen.sdo_direct import parse_reply, request
from capstan.drivers.interfaces import MotorReading
from capstan.models.common.errors import (DeviceLostError, DeviceTimeoutError, DriveFaultError, DriverError,
                                          StateTransitionError)

__all__ = ["Ds402Control", "NMT_OPERATIONAL"]

logger = logging.getLogger("capstan.drivers.canopen.motor")

NMT_OPERATIONAL = 0x05


class Ds402Control:
    """State-machine walks, fresh SDO reads and the liveness check; mixed into ``CanopenMotor``.

    Expects from the class it is mixed into: the attributes below, ``send_cycle()`` and
    ``_drain() -> bool`` (True if a TPDO arrived).
    """

    TRANSITION_TIMEOUT_S: dict[int, float]
    SDO_TIMEOUT_S: float
    HEARTBEAT_LOSS_PERIODS: int
    config: MotorConfig
    node: canopen.RemoteNode | None
    network: canopen.Network | None
    mode: OpMode
    state: State402
    reading: MotorReading
    nmt_state: int | None
    _bus: can.BusABC | None
    _direct: bool
    _sdo_reply: bytes | None
    _new_tpdo: bool
    _hb_last_s: float | None
    _fault: DriverError | None
    _controlword: int
    _torque_permille: int
    _expect_enabled: bool

    def send_cycle(self) -> None:  # pragma: no cover - provided by CanopenMotor
        raise NotImplementedError

    def _drain(self) -> bool:  # pragma: no cover - provided by CanopenMotor
        raise NotImplementedError

    # ================================================================ SDO now
    def _sdo_now(self, index: int, sub: int = 0, value: int | None = None) -> int | None:
        """SDO read (``value`` None) or write, answered now; cyclic frames keep going meanwhile.

        :raises DeviceLostError: if the drive's heartbeat stops while waiting.
        :raises DeviceTimeoutError: if no answer within :attr:`SDO_TIMEOUT_S`.
        :raises SdoRefusedError: if the drive aborts (object and abort text named).
        """
        obj = self.node.object_dictionary[index]
        var = obj if isinstance(obj, canopen.objectdictionary.ODVariable) else obj[sub]
        if not self._direct:
            if value is None:
                return sdo_read(self.node, index, sub)
            sdo_write(self.node, index, sub, value)
            return None
        nid = self.config.node_id
        self._sdo_reply = None
        try:
            self._bus.send(can.Message(arbitration_id=0x600 + nid, data=request(var, value),
                                       is_extended_id=False))
        except can.CanError as exc:
            raise DriverError(f"CAN send failed: {exc}") from exc
        deadline = time.monotonic() + self.SDO_TIMEOUT_S
        while self._sdo_reply is None:
            self._check_alive()
            if time.monotonic() > deadline:
                raise DeviceTimeoutError(f"drive {nid}: SDO {'read' if value is None else 'write'} "
                                         f"0x{index:04X}:{sub:02X}: no answer within {self.SDO_TIMEOUT_S} s")
            self._step()
        return parse_reply(var, self._sdo_reply, nid, value is None)

    def _refresh_state(self) -> State402:
        """Statusword read over SDO now (a drive outside NMT OPERATIONAL sends no TPDO)."""
        sw = int(self._sdo_now(0x6041))
        self.reading.statusword = sw
        self.state = decode_statusword(sw)
        return self.state

    def _begin_wait(self) -> None:
        """Start of a blocking action: the drive gets one whole heartbeat timeout from now to
        show a heartbeat (after a host stall its last one is old without the drive being gone)."""
        self._wait_start_s = time.monotonic()

    def _check_alive(self) -> None:
        """:raises DeviceLostError: if no heartbeat came for 3 drive heartbeat periods, counted from
            the later of the last heartbeat and :meth:`_begin_wait`."""
        self._drain()
        limit_s = self.HEARTBEAT_LOSS_PERIODS * self.config.drive_heartbeat_period_s
        if self._hb_last_s is None:
            return
        now = time.monotonic()
        if now - max(self._hb_last_s, getattr(self, "_wait_start_s", -math.inf)) > limit_s:
            raise DeviceLostError(f"drive {self.config.node_id} is gone (device loss): no heartbeat for "
                                  f"{(now - self._hb_last_s) * 1000:.0f} ms, none during "
                                  f"{limit_s * 1000:.0f} ms (3 periods) of trying to reach it")

    # =========================================================== state machine
    def _step(self) -> None:
        """One blocking-phase cycle: send, wait one period, drain (faults latched, not raised)."""
        self.send_cycle()
        time.sleep(self.config.cycle_period_s)
        self._new_tpdo = self._drain()

    def _goto(self, target: State402) -> None:
        """Walk the transition table to ``target`` from the statusword read now, re-planning after
        every state change; the drive gone is :class:`DeviceLostError` within one heartbeat timeout."""
        self._torque_permille = 0
        self._check_alive()
        self._refresh_state()
        for _ in range(8):
            if self.state == target:
                return
            self._wait_automatic()
            path = path_to(self.state, target)
            if (self.state == State402.QUICK_STOP_ACTIVE and path and path[0].number == 16
                    and not 5 <= self.config.quick_stop_option <= 8):
                path = path_to(self.state, State402.SWITCH_ON_DISABLED)  # 16 needs 0x605A 5..8: via 12
            if not path:
                break
            t = path[0]
            if t.command == Command402.FAULT_RESET:
                self._set_controlword(0x0000)  # bit 7 low first: a real rising edge
                self._step()
            self._set_controlword(CONTROLWORD[t.command])
            timeout_s = self.TRANSITION_TIMEOUT_S.get(t.number, t.timeout_s)
            deadline = time.monotonic() + timeout_s
            while self.state == t.source:
                self._check_alive()
                if time.monotonic() > deadline:
                    raise StateTransitionError(
                        f"DS402 transition {t.number} ({t.source.name} -> {t.target.name}) not done in "
                        f"{timeout_s} s; statusword {describe_statusword(self.reading.statusword)}")
                self._step()
                if not self._new_tpdo:
                    self._refresh_state()
            if t.number == 15 and self.state != State402.FAULT:
                self._fault = None
            if self.state in (State402.FAULT, State402.FAULT_REACTION_ACTIVE):
                raise self._fault or DriveFaultError(f"drive fault during transition {t.number}: "
                                                     f"{describe_statusword(self.reading.statusword)}")
        raise StateTransitionError(f"no DS402 path from {self.state.name} to {target.name}")

    def _set_controlword(self, cw: int) -> None:
        """Controlword for the next RPDO; also over SDO while the drive is not NMT OPERATIONAL
        (it takes no RPDO then, e.g. after its reaction to a lost heartbeat, 0x1029)."""
        self._controlword = cw
        if self.nmt_state is not None and self.nmt_state != NMT_OPERATIONAL:
            self._sdo_now(0x6040, 0, cw)

    def _wait_automatic(self) -> None:
        """Let the drive finish an automatic transition (1: NOT READY, 14: FAULT REACTION)."""
        for number, state in ((1, State402.NOT_READY_TO_SWITCH_ON), (14, State402.FAULT_REACTION_ACTIVE)):
            timeout_s = self.TRANSITION_TIMEOUT_S[number]
            deadline = time.monotonic() + timeout_s
            while self.state == state:
                if time.monotonic() > deadline:
                    raise StateTransitionError(f"drive stays in {state.name} (automatic transition "
                                               f"{number} not done in {timeout_s} s)")
                self._step()
                self._refresh_state()

    def enable(self) -> None:
        """Bring the drive to OPERATION ENABLED (zero torque), verified on a fresh 0x6041, 0x6061
        and the drive's heartbeat (NMT OPERATIONAL).

        :raises DriveFaultError: if the drive is or goes in FAULT.
        :raises StateTransitionError: if a transition exceeds its timeout, or the drive does not
            show OPERATION ENABLED, the mode and NMT OPERATIONAL afterwards.
        :raises DeviceLostError: if the drive's heartbeat stops.
        """
        self._begin_wait()
        self._drain()
        nid = self.config.node_id
        if self._refresh_state() in (State402.FAULT, State402.FAULT_REACTION_ACTIVE):
            raise self._fault or DriveFaultError(
                f"drive {nid} is in {self.state.name} ({describe_statusword(self.reading.statusword)}); "
                f"call fault_reset() first")
        self._goto(State402.OPERATION_ENABLED)
        self._step()
        mode = int(self._sdo_now(0x6061))
        if self._refresh_state() != State402.OPERATION_ENABLED or mode != int(self.mode) or \
                self.nmt_state != NMT_OPERATIONAL:
            nmt = "none seen" if self.nmt_state is None else f"0x{self.nmt_state:02X}"
            raise StateTransitionError(
                f"drive {nid} not enabled: statusword {describe_statusword(self.reading.statusword)}, "
                f"0x6061 mode {mode} (want {int(self.mode)} {self.mode.name}), NMT state {nmt} "
                f"(want 0x05 OPERATIONAL)")
        self.reading.mode = mode
        self._expect_enabled = True

    def disable(self) -> None:
        """Zero torque and shut down to READY TO SWITCH ON (transition 8); bounded.

        :raises DeviceLostError: if the drive is gone (no heartbeat for 3 periods): given up
            within that time, not after the transition timeouts.
        """
        self._expect_enabled = False
        self._torque_permille = 0
        if self.network is None:
            return
        self._begin_wait()
        try:
            self._check_alive()
            if self._refresh_state() in (State402.FAULT, State402.FAULT_REACTION_ACTIVE):
                return  # torque is off; the fault stays for inspection
            self._goto(State402.READY_TO_SWITCH_ON)
        except DeviceLostError:
            raise
        except DriverError as exc:
            logger.error("drive %d: disable incomplete: %s", self.config.node_id, exc)

    def quick_stop(self) -> None:
        """Command QUICK STOP (transition 11) and wait until the drive reports it (or SWITCH ON DISABLED).

        :raises StateTransitionError: if the drive does not react in time.
        """
        self._expect_enabled = False
        self._torque_permille = 0
        self._begin_wait()
        self._controlword = CONTROLWORD[Command402.QUICK_STOP]
        timeout_s = self.TRANSITION_TIMEOUT_S[11]
        deadline = time.monotonic() + timeout_s
        while self.state not in (State402.QUICK_STOP_ACTIVE, State402.SWITCH_ON_DISABLED):
            self._check_alive()
            if time.monotonic() > deadline:
                raise StateTransitionError(f"quick stop (transition 11) not done in {timeout_s} s; "
                                           f"statusword {describe_statusword(self.reading.statusword)}")
            self._step()
            if not self._new_tpdo:
                self._refresh_state()

    def fault_reset(self) -> None:
        """Clear the latched fault and reset the drive (rising edge of controlword bit 7, transition 15).

        :raises StateTransitionError: if the drive stays in FAULT.
        """
        self._expect_enabled = False
        self._fault = None
        self._begin_wait()
        self._drain()
        if self._refresh_state() in (State402.FAULT, State402.FAULT_REACTION_ACTIVE, State402.UNKNOWN):
            self._goto(State402.SWITCH_ON_DISABLED)
        self._fault = None
