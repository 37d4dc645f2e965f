"""Torque profiles of the bring-up moves (run by :mod:`capstan.tools.rig.step_run`).

* :class:`Rest` — zero torque for a while (zero of the load cells, gyro bias);
* :class:`CheckMove` — a small torque-limited move each way: the torque ramps until the
  motor has moved ``move_rad`` (or refuses at ``tau_limit_Nm`` if it has not moved
  ``min_move_rad``), holds, ramps back to zero and rests; the hold windows are what the
  check and the scale calibration compare.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

from capstan.tools.rig.start_config import BringupStop


@dataclass
class Rest:
    """Zero torque for ``duration_s`` [s]."""

    duration_s: float

    def torque_Nm(self, t_s: float, r: Any) -> float:
        return 0.0

    def done(self, t_s: float) -> bool:
        return t_s >= self.duration_s


class MovePhase(IntEnum):
    """Phase of a :class:`CheckMove`."""

    REST = 0
    RAMP = 1
    HOLD = 2
    RELEASE = 3
    SETTLE = 4
    DONE = 5


@dataclass
class CheckMove:
    """One move each way (+ first), torque-limited, with holds at rest.

    :ivar tau_limit_Nm: largest torque it may command [Nm].
    :ivar move_rad: motor travel at which the ramp stops [rad].
    :ivar min_move_rad: travel below which, at ``tau_limit_Nm``, the drive "does not move" [rad].
    :ivar rate_Nm_s: torque ramp rate [Nm/s].
    :ivar rest_s: zero-torque time before the first move [s].
    :ivar hold_s: hold time at the reached torque [s].
    :ivar settle_s: zero-torque time after each release [s].
    :ivar windows: (label, t_start_s, t_end_s) of the rest and the last half of each hold.
    """

    tau_limit_Nm: float
    move_rad: float = 0.15
    min_move_rad: float = 0.01
    rate_Nm_s: float = 2.0
    rest_s: float = 1.0
    hold_s: float = 1.2
    settle_s: float = 0.8
    windows: list[tuple[str, float, float]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.phase = MovePhase.REST
        self.direction = 1.0
        self._t_phase = 0.0
        self._q0 = math.nan
        self._tau = 0.0

    def _enter(self, phase: MovePhase, t_s: float) -> None:
        self.phase, self._t_phase = phase, t_s

    def torque_Nm(self, t_s: float, r: Any) -> float:
        """See :class:`capstan.tools.rig.step_run.Profile`.

        :raises BringupStop: if the motor has not moved ``min_move_rad`` at ``tau_limit_Nm``.
        """
        q_m = float(r["q_m_rad"])
        dt = t_s - self._t_phase
        if self.phase == MovePhase.REST:
            if dt >= self.rest_s:
                self.windows.append(("rest", 0.2 * self.rest_s, self.rest_s))
                self._q0 = q_m
                self._enter(MovePhase.RAMP, t_s)
            return 0.0
        if self.phase == MovePhase.RAMP:
            self._tau = self.direction * min(self.rate_Nm_s * dt, self.tau_limit_Nm)
            moved = abs(q_m - self._q0)
            if moved >= self.move_rad:
                self._enter(MovePhase.HOLD, t_s)
            elif abs(self._tau) >= self.tau_limit_Nm and dt >= self.tau_limit_Nm / self.rate_Nm_s + 0.5:
                if moved < self.min_move_rad:
                    raise BringupStop("check", f"the drive does not move: {moved * 1e3:.1f} mrad of motor travel "
                                               f"at {self._tau:+.2f} Nm for 0.5 s (brake on, motor unpowered, "
                                               f"or the transmission blocked?)")
                self._enter(MovePhase.HOLD, t_s)
            return self._tau
        if self.phase == MovePhase.HOLD:
            if dt >= self.hold_s:
                label = "hold_pos" if self.direction > 0 else "hold_neg"
                self.windows.append((label, t_s - 0.4 * self.hold_s, t_s))
                self._enter(MovePhase.RELEASE, t_s)
            return self._tau
        if self.phase == MovePhase.RELEASE:
            tau = self._tau - math.copysign(min(self.rate_Nm_s * dt, abs(self._tau)), self._tau)
            if tau == 0.0:
                self._enter(MovePhase.SETTLE, t_s)
            return tau
        if self.phase == MovePhase.SETTLE:
            if dt >= self.settle_s:
                if self.direction > 0:
                    self.direction = -1.0
                    self._q0 = q_m
                    self._enter(MovePhase.RAMP, t_s)
                else:
                    self._enter(MovePhase.DONE, t_s)
            return 0.0
        return 0.0

    def done(self, t_s: float) -> bool:
        return self.phase == MovePhase.DONE

    @property
    def max_duration_s(self) -> float:
        """Upper bound of the move's length [s]."""
        ramp = self.tau_limit_Nm / self.rate_Nm_s + 0.6
        return self.rest_s + 2 * (2 * ramp + self.hold_s + self.settle_s) + 2.0
