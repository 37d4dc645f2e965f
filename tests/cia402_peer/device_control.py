"""The peer's device-control state machine (CiA 402-2 §6.3: states, transitions 2-16, the
statusword of table 30) and its torque stage (0x6072 cap, quick-stop and shutdown ramps),
written from the spec like the rest of the peer; nothing from capstan is imported.

:class:`DeviceControl` is a mixin of :class:`cia402_peer.drive.PeerDrive`: it reads and writes
the drive's ``state``, ``od``, ``_cw``, ``_ramp``, ``_applied``, ``_target``,
``_mode_display``, ``internal_limit`` and ``ramp_s``, and sends the EMCY of a fault reset
through its ``_emcy``.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Any

class Ds402(IntEnum):
    NOT_READY = 0
    SWITCH_ON_DISABLED = 1
    READY_TO_SWITCH_ON = 2
    SWITCHED_ON = 3
    OPERATION_ENABLED = 4
    QUICK_STOP_ACTIVE = 5
    FAULT_REACTION_ACTIVE = 6
    FAULT = 7


#: statusword bits 0-6 per state, CiA 402-2 table 30 (bit 4 voltage enabled where powered)
_SW = {Ds402.NOT_READY: 0x00, Ds402.SWITCH_ON_DISABLED: 0x40, Ds402.READY_TO_SWITCH_ON: 0x31,
       Ds402.SWITCHED_ON: 0x33, Ds402.OPERATION_ENABLED: 0x37, Ds402.QUICK_STOP_ACTIVE: 0x17,
       Ds402.FAULT_REACTION_ACTIVE: 0x1F, Ds402.FAULT: 0x18}
_TORQUE_MODES = (4, 10)


class DeviceControl:
    """Controlword -> state transitions, the statusword, and the torque actually applied."""

    state: Ds402
    od: dict[Any, Any]
    _cw: int
    _ramp: tuple[str, float, float] | None
    _applied: float
    _target: int
    _mode_display: int
    internal_limit: bool
    ramp_s: float

    def od_value(self, index: int, sub: int, default: int) -> int:
        """The value of object ``index:sub``, or ``default`` when the EDS does not define it."""
        e = self.od.get((index, sub))
        return default if e is None else e.value

    def statusword(self) -> int:
        sw = _SW[self.state] | 0x0200
        if self.internal_limit and self.state == Ds402.OPERATION_ENABLED:
            sw |= 0x0800
        return sw

    def _quick_stop(self, now: float) -> None:
        self.state = Ds402.QUICK_STOP_ACTIVE
        option = self.od_value(0x605A, 0, 2)
        if option == 0:
            self.state = Ds402.SWITCH_ON_DISABLED
        else:
            self._ramp = ("quick_stop", now, self._applied)

    def _controlword(self, cw: int, now: float) -> None:
        edge = bool(cw & 0x80) and not self._cw & 0x80
        self._cw = cw
        s, S = self.state, Ds402
        if s == S.FAULT:
            if edge:   # transition 15
                self.state = S.SWITCH_ON_DISABLED
                self.od[(0x603F, 0)].value = 0
                self.od[(0x1001, 0)].value = 0
                self._emcy(0, 0)
            return
        if s in (S.NOT_READY, S.FAULT_REACTION_ACTIVE) or cw & 0x80:
            return
        low = cw & 0x0F
        disable_voltage = not cw & 0x02
        quick = bool(cw & 0x02) and not cw & 0x04
        shutdown, switch_on, enable = cw & 0x07 == 0x06, low == 0x07, low == 0x0F
        if s == S.SWITCH_ON_DISABLED and shutdown:
            self.state = S.READY_TO_SWITCH_ON                                     # 2
        elif s == S.READY_TO_SWITCH_ON:
            if switch_on or enable:
                self.state = S.OPERATION_ENABLED if enable else S.SWITCHED_ON    # 3 (+4)
            elif disable_voltage or quick:
                self.state = S.SWITCH_ON_DISABLED                                 # 7
        elif s == S.SWITCHED_ON:
            if enable:
                self.state = S.OPERATION_ENABLED                                  # 4
            elif shutdown:
                self.state = S.READY_TO_SWITCH_ON                                 # 6
            elif disable_voltage or quick:
                self.state = S.SWITCH_ON_DISABLED                                 # 10
        elif s == S.OPERATION_ENABLED:
            if switch_on:
                self.state = S.SWITCHED_ON                                        # 5
            elif shutdown:
                option = self.od_value(0x605B, 0, 0)
                if option == 1:
                    self._ramp = ("shutdown", now, self._applied)               # 8 after the ramp
                else:
                    self.state = S.READY_TO_SWITCH_ON                             # 8
            elif disable_voltage:
                self.state = S.SWITCH_ON_DISABLED                                 # 9
            elif quick:
                self._quick_stop(now)                                             # 11
        elif s == S.QUICK_STOP_ACTIVE:
            option = self.od_value(0x605A, 0, 2)
            if disable_voltage:
                self.state, self._ramp = S.SWITCH_ON_DISABLED, None               # 12
            elif enable and 5 <= option <= 8:
                self.state, self._ramp = S.OPERATION_ENABLED, None                # 16

    def _update_torque(self, now: float) -> None:
        limit = self.od_value(0x6072, 0, 1000)
        if self._ramp is not None:
            kind, t0, start = self._ramp
            frac = max(0.0, 1.0 - (now - t0) / self.ramp_s)
            self._applied = start * frac
            if frac == 0.0:
                self._ramp = None
                option = self.od_value(0x605A, 0, 2)
                if kind == "shutdown" and self.state == Ds402.OPERATION_ENABLED:
                    self.state = Ds402.READY_TO_SWITCH_ON
                elif kind == "quick_stop" and self.state == Ds402.QUICK_STOP_ACTIVE and option <= 4:
                    self.state = Ds402.SWITCH_ON_DISABLED
            return
        if self.state == Ds402.OPERATION_ENABLED and self._mode_display in _TORQUE_MODES:
            self.internal_limit = abs(self._target) > limit
            self._applied = float(max(-limit, min(limit, self._target)))
        else:
            self.internal_limit = False
            self._applied = 0.0
